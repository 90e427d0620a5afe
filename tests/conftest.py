"""Shared fixtures: one compiled checker per env id for the whole session."""

from __future__ import annotations

import os

os.environ.setdefault("MUJOCO_GL", "egl")

import pytest

import jaxenvs
from jaxenvs.testing import TaskChecker

_CHECKERS: dict[str, TaskChecker] = {}


def checker_for(env_id: str) -> TaskChecker:
    if env_id not in _CHECKERS:
        _CHECKERS[env_id] = TaskChecker(jaxenvs.make(env_id))
    return _CHECKERS[env_id]


@pytest.fixture(scope="session")
def get_checker():
    return checker_for
