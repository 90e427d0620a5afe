"""JAX's persistent compilation cache, on by default for the command line.

A compiled program (the training chunk, the evaluation rollout, ...) is stored on disk
keyed by its HLO, the JAX/XLA versions and the device, so a second run of the same task
and config skips compiling. The command line calls :func:`enable` unless given
``--no-compile-cache``; library users opt in by calling it themselves.

While it is on, the trainers' traced programs are stored too, in its ``programs/``
subdirectory (:mod:`jaxenvs.program_cache`), so that a warm run skips tracing as well.

The directory is per user: ``$JAXENVS_CACHE_DIR`` if set, else
``$XDG_CACHE_HOME/jaxenvs/jax-compile`` (``~/.cache/jaxenvs/jax-compile``).

Trust. JAX's own file cache, as shipped, is unbounded, and with no size limit it neither
locks nor checks what it reads: a damaged entry costs a recompile and a warning on every
later run (it is never replaced), and a file copied over another key's loads the other
program. :func:`enable` therefore

* bounds the cache (``jax_compilation_cache_max_size``, :data:`DEFAULT_MAX_BYTES`), which
  also turns on JAX's file lock around every read and write (several processes may share
  one directory) and its least-recently-used eviction;
* has JAX build its cache as a :class:`VerifiedCache`: every entry carries a SHA-256 of its
  key and content, and an entry that does not verify (flipped bytes, truncated, another
  key's, written by an older version) is removed with one warning, so JAX compiles the
  program again and stores the new entry. A damaged entry costs one recompile, never a
  failed run or a wrong program.
"""

from __future__ import annotations

import contextlib
import hashlib
import os
from pathlib import Path
from typing import Any

import jax
from jax._src import compilation_cache as _jax_cache
from jax._src import lru_cache as _jax_lru

from jaxenvs.program_cache import notice

ENV_VAR = "JAXENVS_CACHE_DIR"
#: the cache's size limit unless :func:`enable` is given another (least recently used
#: entries are evicted past it)
DEFAULT_MAX_BYTES = 2 * 1024**3
_ACTIVE: list[Path] = []  # the directory enable() turned on, if any
#: an entry: MAGIC, SHA-256 of (key, content), content (JAX's compressed executable)
MAGIC = b"jaxenvs-xla-1\n"
_DIGEST = 32


def _digest(key: str, value: bytes) -> bytes:
    return hashlib.sha256(key.encode() + b"\0" + value).digest()


def seal(key: str, value: bytes) -> bytes:
    """The stored form of cache entry ``value`` under ``key``."""
    return MAGIC + _digest(key, value) + value


def unseal(key: str, blob: bytes) -> bytes | None:
    """The content of stored entry ``blob`` if it verifies for ``key``, else ``None``."""
    start = len(MAGIC) + _DIGEST
    if not blob.startswith(MAGIC) or len(blob) < start:
        return None
    value = blob[start:]
    return value if _digest(key, value) == blob[len(MAGIC) : start] else None


class VerifiedCache(_jax_lru.LRUCache):
    """JAX's file cache (bounded, locked, LRU) with entries that verify themselves.

    ``get`` returns an entry only if its digest matches its key and content; otherwise it
    removes the entry (with one warning) and returns ``None``, so JAX compiles again and
    ``put`` stores a good entry. Entries without an access-time file (written by an
    unbounded cache) are given the oldest access time instead of breaking eviction.
    """

    def get(self, key: str) -> bytes | None:
        blob = super().get(key)
        if blob is None:
            return None
        value = unseal(key, blob)
        if value is None:
            notice(
                f"discarding damaged compile-cache entry {key[:60]} in {self.path}; "
                "compiling it again"
            )
            self._remove(key)
        return value

    def put(self, key: str, value: bytes) -> None:
        super().put(key, seal(key, value))

    def _remove(self, key: str) -> None:
        lock = self.lock if self.eviction_enabled else contextlib.nullcontext()
        with lock:
            for suffix in (_jax_lru._CACHE_SUFFIX, _jax_lru._ATIME_SUFFIX):
                with contextlib.suppress(OSError):
                    (self.path / f"{key}{suffix}").unlink()

    def _evict_if_needed(self, *, additional_size: int = 0) -> None:
        for entry in self.path.glob(f"*{_jax_lru._CACHE_SUFFIX}"):
            key = entry.name.removesuffix(_jax_lru._CACHE_SUFFIX)
            atime = self.path / f"{key}{_jax_lru._ATIME_SUFFIX}"
            if not atime.exists():
                with contextlib.suppress(OSError):
                    atime.write_bytes((0).to_bytes(8, "little"))
        super()._evict_if_needed(additional_size=additional_size)


def _verified_file_cache(path: str) -> tuple[Any, str] | None:
    """What JAX calls to build its file cache: a :class:`VerifiedCache` of the configured
    size (unbounded, with a warning, if the ``filelock`` package it needs is missing)."""
    max_size = _jax_cache.config.compilation_cache_max_size.value
    try:
        return VerifiedCache(path, max_size=max_size), path
    except RuntimeError as err:  # filelock missing, or a remote file system
        notice(f"compile cache unbounded and unlocked: {err}")
        return VerifiedCache(path, max_size=-1), path


def install_verified_cache() -> None:
    """Have JAX build its file cache as a :class:`VerifiedCache` from now on (whatever
    directory it is given); the cache is rebuilt at its next use."""
    _jax_cache.get_file_cache = _verified_file_cache
    _jax_cache.reset_cache()


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
    jax.config.update("jax_compilation_cache_max_size", int(max_bytes))
    jax.config.update("jax_compilation_cache_dir", str(cache))
    jax.config.update("jax_persistent_cache_min_compile_time_secs", float(min_compile_secs))
    jax.config.update("jax_persistent_cache_min_entry_size_bytes", 0)
    install_verified_cache()  # JAX builds its cache once: rebuilt for these settings
    _ACTIVE[:] = [cache]
    return cache


def active() -> Path | None:
    """The directory :func:`enable` turned on in this process (``None``: off)."""
    return _ACTIVE[0] if _ACTIVE else None


def disable() -> None:
    """Turn the persistent compilation cache off for this process."""
    jax.config.update("jax_compilation_cache_dir", None)
    _jax_cache.reset_cache()
    _ACTIVE.clear()
