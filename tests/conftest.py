"""Shared fixtures: one compiled checker per env id for the whole session."""

from __future__ import annotations

import os
import tempfile

os.environ.setdefault("MUJOCO_GL", "egl")
# a command-line test that switches the compile cache on writes here, not to ~/.cache
os.environ["JAXENVS_CACHE_DIR"] = tempfile.mkdtemp(prefix="jaxenvs-test-cache-")

import pytest

import jaxenvs
from jaxenvs import compile_cache
from jaxenvs.testing import TaskChecker

_CHECKERS: dict[str, TaskChecker] = {}


def checker_for(env_id: str) -> TaskChecker:
    if env_id not in _CHECKERS:
        _CHECKERS[env_id] = TaskChecker(jaxenvs.make(env_id))
    return _CHECKERS[env_id]


@pytest.fixture(scope="session")
def get_checker():
    return checker_for


@pytest.fixture(autouse=True)
def _compile_cache_stays_off():
    """A test that switches the persistent compile cache (and with it the program store)
    on does not leave it on for the tests after it."""
    yield
    if compile_cache.active() is not None:
        compile_cache.disable()
