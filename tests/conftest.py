"""Shared fixtures: one compiled checker per env id for the whole session."""

from __future__ import annotations

import os
import tempfile

os.environ.setdefault("MUJOCO_GL", "egl")
# one persistent compile cache for the whole test session, in a fresh directory (never
# ~/.cache): modules that build the same programs (an env's step, a trainer's chunk)
# compile them once per session. Command-line tests that switch the cache on use it too.
os.environ["JAXENVS_CACHE_DIR"] = tempfile.mkdtemp(prefix="jaxenvs-test-cache-")

import jax
import pytest

import jaxenvs
from jaxenvs import compile_cache
from jaxenvs.testing import TaskChecker

_SESSION_CACHE = os.environ["JAXENVS_CACHE_DIR"]
_CHECKERS: dict[str, TaskChecker] = {}


def checker_for(env_id: str) -> TaskChecker:
    if env_id not in _CHECKERS:
        _CHECKERS[env_id] = TaskChecker(jaxenvs.make(env_id))
    return _CHECKERS[env_id]


@pytest.fixture(scope="session")
def get_checker():
    return checker_for


def _session_compile_cache() -> None:
    """JAX's persistent cache on, in the session directory, without the program store
    (:func:`jaxenvs.compile_cache.active` stays ``None``; tests of the store switch it on
    themselves)."""
    jax.config.update("jax_compilation_cache_dir", _SESSION_CACHE)
    jax.config.update("jax_persistent_cache_min_compile_time_secs", 1.0)


_session_compile_cache()


@pytest.fixture(autouse=True)
def _program_store_stays_off():
    """A test that switches the command line's cache (and with it the program store) on
    does not leave the store on for the tests after it."""
    yield
    if compile_cache.active() is not None:
        compile_cache.disable()
        _session_compile_cache()
