"""Entries of JAX's compile cache that verify themselves: the one module that reads JAX's
internals (``jax._src``), on the JAX versions it was written and tested against.

JAX's file cache, bounded (``jax_compilation_cache_max_size``), locks its files and evicts
the least recently used entries, but does not check what it reads: a damaged entry costs a
recompile and a warning on every later run (it is never replaced), and a file copied over
another key's loads the other program. :func:`install` has JAX build its cache as a
``VerifiedCache`` instead: every entry carries a SHA-256 of its key and content, and an
entry that does not verify (flipped bytes, truncated, another key's, written without a
digest) is removed with one warning, so JAX compiles the program again and stores the new
entry.

JAX offers no public hook for this, so the cache subclasses ``jax._src.lru_cache.LRUCache``
and replaces ``jax._src.compilation_cache.get_file_cache``. Both are private and may change
in any release, hence :data:`TESTED_JAX`: on any other JAX version :func:`supported` is
false, :func:`install` leaves JAX alone and the cache is JAX's own (bounded, locked, LRU,
configured through the public ``jax.config``), without per-entry checks.
"""

from __future__ import annotations

import contextlib
import functools
import hashlib
from pathlib import Path
from typing import Any

import jax

from jaxenvs.run.program_cache import notice

#: the JAX releases (major, minor) this module was written and tested against
TESTED_JAX = ((0, 10), (0, 11))
#: an entry: MAGIC, SHA-256 of (key, content), content (JAX's compressed executable)
MAGIC = b"jaxenvs-xla-1\n"
_DIGEST = 32
_ORIGINAL: list[Any] = []  # JAX's own get_file_cache while ours is installed


def jax_release(version: str | None = None) -> tuple[int, int]:
    """``(major, minor)`` of ``version`` (default: the installed ``jax.__version__``)."""
    major, minor, *_ = (version or jax.__version__).split(".")
    return int(major), int("".join(c for c in minor if c.isdigit()) or 0)


def supported() -> bool:
    """True on a JAX release in :data:`TESTED_JAX` (where :func:`install` hooks in)."""
    return jax_release() in TESTED_JAX


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


@functools.cache
def _verified_cache_type() -> type:
    """``VerifiedCache``, built on first use (on a tested JAX only)."""
    from jax._src import lru_cache

    cache_suffix, atime_suffix = lru_cache._CACHE_SUFFIX, lru_cache._ATIME_SUFFIX

    class VerifiedCache(lru_cache.LRUCache):  # type: ignore[misc]
        """JAX's file cache (bounded, locked, LRU) with entries that verify themselves.

        ``get`` returns an entry only if its digest matches its key and content; otherwise
        it removes the entry (with one warning) and returns ``None``, so JAX compiles again
        and ``put`` stores a good entry. Entries without an access-time file (written by an
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
                for suffix in (cache_suffix, atime_suffix):
                    with contextlib.suppress(OSError):
                        (self.path / f"{key}{suffix}").unlink()

        def _evict_if_needed(self, *, additional_size: int = 0) -> None:
            for entry in self.path.glob(f"*{cache_suffix}"):
                atime = self.path / f"{entry.name.removesuffix(cache_suffix)}{atime_suffix}"
                if not atime.exists():
                    with contextlib.suppress(OSError):
                        atime.write_bytes((0).to_bytes(8, "little"))
            super()._evict_if_needed(additional_size=additional_size)

    return VerifiedCache


def verified_cache(path: str | Path, max_size: int) -> Any:
    """A ``VerifiedCache`` in ``path`` holding at most ``max_size`` bytes (``-1``:
    unbounded); on a tested JAX only."""
    return _verified_cache_type()(str(path), max_size=max_size)


def _verified_file_cache(path: str) -> tuple[Any, str] | None:
    """What JAX calls to build its file cache: a ``VerifiedCache`` of the configured size
    (unbounded, with a warning, if the ``filelock`` package it needs is missing)."""
    max_size = int(jax.config.jax_compilation_cache_max_size)  # type: ignore[attr-defined]
    try:
        return verified_cache(path, max_size), path
    except RuntimeError as err:  # filelock missing, or a remote file system
        notice(f"compile cache unbounded and unlocked: {err}")
        return verified_cache(path, -1), path


def install() -> bool:
    """Have JAX build its file cache as a ``VerifiedCache`` from now on; returns whether it
    does (``False`` on an untested JAX, whose own cache is then left as it is). The cache
    is built anew at its next use once the caller resets it."""
    if not supported():
        remove()
        return False
    from jax._src import compilation_cache

    if not _ORIGINAL:
        _ORIGINAL.append(compilation_cache.get_file_cache)
    compilation_cache.get_file_cache = _verified_file_cache
    return True


def remove() -> None:
    """Give JAX its own file cache back (nothing to do if :func:`install` did not hook in)."""
    if not _ORIGINAL:
        return
    from jax._src import compilation_cache

    compilation_cache.get_file_cache = _ORIGINAL.pop()
