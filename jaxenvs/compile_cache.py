"""JAX's persistent compilation cache, on by default for the command line.

A compiled program (the training chunk, the evaluation rollout, ...) is stored on disk
keyed by its HLO, the JAX/XLA versions and the device, so a second run of the same task
and config skips compiling. The command line calls :func:`enable` unless given
``--no-compile-cache``; library users opt in by calling it themselves.

While it is on, the trainers' traced programs are stored too, in its ``programs/``
subdirectory (:mod:`jaxenvs.program_cache`), so that a warm run skips tracing as well.

The directory is per user: ``$JAXENVS_CACHE_DIR`` if set, else
``$XDG_CACHE_HOME/jaxenvs/jax-compile`` (``~/.cache/jaxenvs/jax-compile``).
"""

from __future__ import annotations

import os
from pathlib import Path

import jax

ENV_VAR = "JAXENVS_CACHE_DIR"
_ACTIVE: list[Path] = []  # the directory enable() turned on, if any


def default_cache_dir() -> Path:
    """The per-user cache directory (see the module docstring)."""
    explicit = os.environ.get(ENV_VAR)
    if explicit:
        return Path(explicit).expanduser()
    base = os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache"
    return Path(base).expanduser() / "jaxenvs" / "jax-compile"


def enable(path: str | Path | None = None, min_compile_secs: float = 0.0) -> Path | None:
    """Turn the persistent compilation cache on; returns its directory.

    Args:
      path: cache directory; ``None`` uses :func:`default_cache_dir`.
      min_compile_secs: only programs that took at least this long to compile are stored
        (0 stores every program, including the many small ones a run compiles).

    An unwritable directory leaves the cache off (returns ``None``) rather than failing
    the run: the cache only saves time.
    """
    cache = Path(path).expanduser() if path is not None else default_cache_dir()
    try:
        cache.mkdir(parents=True, exist_ok=True)
    except OSError:
        return None
    if not os.access(cache, os.W_OK):
        return None
    jax.config.update("jax_compilation_cache_dir", str(cache))
    jax.config.update("jax_persistent_cache_min_compile_time_secs", float(min_compile_secs))
    jax.config.update("jax_persistent_cache_min_entry_size_bytes", 0)
    _ACTIVE[:] = [cache]
    return cache


def active() -> Path | None:
    """The directory :func:`enable` turned on in this process (``None``: off)."""
    return _ACTIVE[0] if _ACTIVE else None


def disable() -> None:
    """Turn the persistent compilation cache off for this process."""
    jax.config.update("jax_compilation_cache_dir", None)
    _ACTIVE.clear()
