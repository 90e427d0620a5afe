"""JAX's persistent compilation cache, on by default for the command line.

A compiled program (the training chunk, the evaluation rollout, ...) is stored on disk
keyed by its HLO, the JAX/XLA versions and the device, so a second run of the same task
and config skips compiling (not tracing: the Python that builds a program runs in every
process). The command line calls :func:`enable` unless given ``--no-compile-cache``;
library users opt in by calling it themselves.

The directory is per user: ``$JAXENVS_CACHE_DIR`` if set, else
``$XDG_CACHE_HOME/jaxenvs/jax-compile`` (``~/.cache/jaxenvs/jax-compile``).

Trust. :func:`enable` configures JAX's own cache through the public ``jax.config`` only.
It bounds the cache (``jax_compilation_cache_max_size``, :data:`DEFAULT_MAX_BYTES`), which
also turns on JAX's file lock around every read and write (several processes may share
one directory) and its least-recently-used eviction. The entries are JAX's: an entry that
does not decompress or deserialise (truncated, flipped bytes) is reported by JAX with a
warning ("Error reading persistent compilation cache entry") and the program is compiled
again, never a failed run; but JAX keeps the damaged file (it never overwrites an entry),
so every later run pays that compile and warning until the entry or the directory is
deleted. JAX does not check that an entry belongs to its key: a file copied over another
key's loads the other program.

A directory that cannot be written leaves the cache off with a one-line warning naming it:
every run then compiles cold.
"""

from __future__ import annotations

import os
import tempfile
import warnings
from pathlib import Path

import jax
from jax.experimental.compilation_cache import compilation_cache as jax_cache

ENV_VAR = "JAXENVS_CACHE_DIR"
#: the cache's size limit unless :func:`enable` is given another (least recently used
#: entries are evicted past it)
DEFAULT_MAX_BYTES = 2 * 1024**3
_ACTIVE: list[Path] = []  # the directory enable() turned on, if any


def notice(message: str) -> None:
    """Warn with ``message`` as one line (a ``UserWarning`` from "jaxenvs", with no source
    line after it): what an unwritable cache costs, never an error."""
    warnings.warn_explicit(message, UserWarning, "jaxenvs", 0)


def writable_problem(directory: Path) -> str | None:
    """Why files cannot be written in ``directory`` (created if missing), or ``None``."""
    try:
        directory.mkdir(parents=True, exist_ok=True)
        with tempfile.NamedTemporaryFile(dir=directory, prefix=".probe-"):
            pass
    except OSError as err:
        return err.strerror or type(err).__name__
    return None


def default_cache_dir() -> Path:
    """The per-user cache directory (see the module docstring)."""
    explicit = os.environ.get(ENV_VAR)
    if explicit:
        return Path(explicit).expanduser()
    base = os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache"
    return Path(base).expanduser() / "jaxenvs" / "jax-compile"


def enable(
    path: str | Path | None = None,
    min_compile_secs: float = 0.0,
    max_bytes: int = DEFAULT_MAX_BYTES,
) -> Path | None:
    """Turn the persistent compilation cache on; returns its directory.

    Args:
      path: cache directory; ``None`` uses :func:`default_cache_dir`.
      min_compile_secs: only programs that took at least this long to compile are stored
        (0 stores every program, including the many small ones a run compiles).
      max_bytes: the size limit of JAX's entries (the least recently used are evicted).

    A directory that cannot be created or written leaves the cache off (returns ``None``)
    with a one-line warning naming it, rather than failing the run: the cache only saves
    time, and without it every program compiles cold.
    """
    cache = Path(path).expanduser() if path is not None else default_cache_dir()
    problem = writable_problem(cache)
    if problem is not None:
        notice(f"compile cache off: cannot write to {cache} ({problem}); runs will compile cold")
        return None
    jax.config.update("jax_compilation_cache_max_size", int(max_bytes))
    jax.config.update("jax_compilation_cache_dir", str(cache))
    jax.config.update("jax_persistent_cache_min_compile_time_secs", float(min_compile_secs))
    jax.config.update("jax_persistent_cache_min_entry_size_bytes", 0)
    jax_cache.reset_cache()  # JAX builds its cache once: rebuilt for these settings
    _ACTIVE[:] = [cache]
    return cache


def active() -> Path | None:
    """The directory :func:`enable` turned on in this process (``None``: off)."""
    return _ACTIVE[0] if _ACTIVE else None


def disable() -> None:
    """Turn the persistent compilation cache off for this process."""
    jax.config.update("jax_compilation_cache_dir", None)
    jax_cache.reset_cache()
    _ACTIVE.clear()
