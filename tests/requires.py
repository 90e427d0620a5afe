"""Tests that need an optional package fail, never skip, when it is missing.

A skipped test is green in CI: a test of the Brax adapter or of the README's
Stable-Baselines3 example that skipped whenever its package failed to install would pass
while checking nothing. ``.ci/run`` installs what each tier needs; on a machine without it
the test fails with one line naming the package and how to install it.
"""

from __future__ import annotations

import importlib
from types import ModuleType

import pytest


def package(module: str, install: str) -> ModuleType:
    """Import ``module``; if that fails, fail the calling test (or module) naming it and
    ``install``, the command that provides it."""
    try:
        return importlib.import_module(module)
    except ImportError as err:
        pytest.fail(f"{module} is needed by this test but not importable ({err}); {install}")
