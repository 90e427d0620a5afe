"""Shared fixtures: programs compiled once per session and reused by every module.

* ``get_checker(env_id, physics="auto")``: the battery of :mod:`jaxenvs.testing` for one id
  and engine; its jitted reset, step, vmapped step and batched rollout compile once, and
  other modules read the rollout's trajectory instead of compiling their own.
* ``get_batched(env_id, num_envs, **overrides)``: a batched env with its jitted reset and
  step, one per (id, batch size, overrides).

``physics="auto"`` (what ``jaxenvs.make`` does by default) is MuJoCo's C engine on a CPU
for the built-in tasks: tests of task logic use it, tests of MJX itself say
``physics="mjx"``.
"""

from __future__ import annotations

import atexit
import os
import shutil
import sys
import tempfile
from collections.abc import Callable
from typing import Any, NamedTuple

# the tests live in a folder per layer; their shared helpers (engines.py, requires.py, ...)
# sit here, importable from every folder
sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
os.environ.setdefault("MUJOCO_GL", "egl")
# one persistent compile cache for the whole test session, in a fresh directory (never
# ~/.cache): modules that build the same programs (an env's step, a trainer's chunk)
# compile them once per session. Command-line tests that switch the cache on use it too.
# Under pytest-xdist every worker process has its own (JAX's file cache is not safe to
# write from two processes at once), removed when its process ends.
os.environ["JAXENVS_CACHE_DIR"] = tempfile.mkdtemp(prefix="jaxenvs-test-cache-")
# Tests compile far more than they run: XLA's CPU backend without LLVM's expensive passes
# compiles in about two thirds of the CPU time, and the programs stay correct (only slower).
# Set here, before JAX starts, so command-line tests' subprocesses inherit it too.
os.environ["XLA_FLAGS"] = " ".join(
    [
        os.environ.get("XLA_FLAGS", ""),
        "--xla_backend_optimization_level=0",
        "--xla_llvm_disable_expensive_passes=true",
    ]
).strip()

import jax
import pytest

import jaxenvs
from jaxenvs.core import BatchedEnv
from jaxenvs.run import compile_cache
from jaxenvs.testing import TaskChecker

_SESSION_CACHE = os.environ["JAXENVS_CACHE_DIR"]
atexit.register(shutil.rmtree, _SESSION_CACHE, ignore_errors=True)
# XLA's compiled programs, shared by every worker of the session: made by the process that
# imports this file first (pytest-xdist's controller, whose environment the workers
# inherit) and removed by it. JAX locks a bounded cache's files, so workers may share it.
if "JAXENVS_TEST_XLA_CACHE" not in os.environ:
    os.environ["JAXENVS_TEST_XLA_CACHE"] = tempfile.mkdtemp(prefix="jaxenvs-test-xla-")
    atexit.register(shutil.rmtree, os.environ["JAXENVS_TEST_XLA_CACHE"], ignore_errors=True)
_XLA_CACHE = os.environ["JAXENVS_TEST_XLA_CACHE"]
_CHECKERS: dict[tuple[str, str], TaskChecker] = {}
_BATCHED: dict[tuple[Any, ...], Batched] = {}


class Batched(NamedTuple):
    """A batched env and its jitted reset and step."""

    env: BatchedEnv
    reset: Callable[..., Any]
    step: Callable[..., Any]


def checker_for(env_id: str, physics: str = "auto") -> TaskChecker:
    if (env_id, physics) not in _CHECKERS:
        _CHECKERS[env_id, physics] = TaskChecker(jaxenvs.make(env_id, physics=physics))
    return _CHECKERS[env_id, physics]


def batched_for(env_id: str, num_envs: int, **overrides: Any) -> Batched:
    key = (env_id, num_envs, *sorted(overrides.items()))
    if key not in _BATCHED:
        benv = jaxenvs.make(env_id, num_envs=num_envs, **overrides)
        assert isinstance(benv, BatchedEnv)
        _BATCHED[key] = Batched(benv, jax.jit(benv.reset), jax.jit(benv.step))
    return _BATCHED[key]


@pytest.fixture(scope="session")
def get_checker():
    return checker_for


@pytest.fixture(scope="session")
def get_batched():
    return batched_for


def _session_compile_cache() -> None:
    """JAX's persistent cache on, in the directory every worker shares, bounded (so JAX
    locks its files); :func:`jaxenvs.run.compile_cache.active` stays ``None`` (tests of the
    command line's cache switch it on themselves)."""
    jax.config.update("jax_compilation_cache_dir", _XLA_CACHE)
    jax.config.update("jax_compilation_cache_max_size", 8 << 30)
    jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.5)


_session_compile_cache()


@pytest.fixture(autouse=True)
def _command_line_cache_stays_off():
    """A test that switches the command line's cache on does not leave it on for the tests
    after it."""
    yield
    if compile_cache.active() is not None:
        compile_cache.disable()
        _session_compile_cache()


def pytest_xdist_auto_num_workers(config: pytest.Config) -> int:
    """``-n auto`` (the default, see pyproject.toml): one test process per usable core, at
    most 8 (each holds its own compiled programs, about 1-2 GB)."""
    return max(1, min(8, len(os.sched_getaffinity(0))))
