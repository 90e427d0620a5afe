"""The compile cache: JAX's own, bounded and locked. A damaged compiled entry costs a
compile and a warning, never a failed run or another result; JAX keeps the damaged file, so
the warning comes back on every run until it is deleted (the README's Reliability section)."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import warnings
from collections.abc import Callable
from pathlib import Path
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxenvs.run import checkpoint, compile_cache, runner

#: the warning JAX gives for a cache entry it cannot read (it then compiles the program)
JAX_READ_ERROR = "Error reading persistent compilation cache entry"


# ------------------------------------------------------- JAX's compile cache, in process
def _program(factor: float) -> Callable[[jax.Array], jax.Array]:
    """A new jitted function each call (so JAX's in-memory cache misses and its file cache
    is read), of the same program for the same ``factor`` (so the same file cache key)."""

    def affine(x: jax.Array) -> jax.Array:
        return x * factor + 1

    return jax.jit(affine)


X = jnp.arange(3.0)


def _truncate(path: Path) -> None:
    path.write_bytes(path.read_bytes()[: path.stat().st_size // 2])


def _flip(path: Path) -> None:
    """Flip bits through the file, its first byte (the compressed frame's header) included."""
    blob = bytearray(path.read_bytes())
    for i in range(0, len(blob), max(1, len(blob) // 7)):
        blob[i] ^= 0x5A
    path.write_bytes(bytes(blob))


def test_enable_bounds_and_locks_the_cache(tmp_path):
    # (the conftest's autouse fixture restores the session's cache afterwards)
    assert compile_cache.enable(tmp_path, max_bytes=10**8) == tmp_path
    assert jax.config.jax_compilation_cache_max_size == 10**8
    _program(7.0)(X).block_until_ready()
    assert (tmp_path / ".lockfile").exists()  # bounded: JAX locks its files
    assert list(tmp_path.glob("jit_affine-*-cache"))
    assert compile_cache.active() == tmp_path


@pytest.mark.parametrize("damage", [_truncate, _flip])
def test_damaged_entry_costs_a_compile_and_stays(tmp_path, damage):
    assert compile_cache.enable(tmp_path, max_bytes=10**8) == tmp_path
    expected = np.asarray(_program(11.0)(X))
    (entry,) = tmp_path.glob("jit_affine-*-cache")
    damage(entry)
    damaged = entry.read_bytes()
    for _ in range(2):  # JAX keeps the damaged entry: each later process reads it again
        with warnings.catch_warnings(record=True) as record:
            warnings.simplefilter("always")
            np.testing.assert_array_equal(_program(11.0)(X), expected)
        assert [w for w in record if JAX_READ_ERROR in str(w.message)], record
        assert entry.read_bytes() == damaged


def test_unwritable_cache_directory_is_named_once(tmp_path):
    blocker = tmp_path / "not-a-dir"
    blocker.write_text("")
    with pytest.warns(UserWarning) as record:
        assert compile_cache.enable(blocker / "cache") is None
    (message,) = [str(w.message) for w in record]
    assert str(blocker / "cache") in message and "compile cold" in message
    assert "\n" not in message
    assert compile_cache.active() is None


# --------------------------------------------- the battery: whole runs on a damaged cache
#: a small run (MJX physics)
TRAIN = [
    sys.executable, "-m", "jaxenvs", "train", "CartPole-v0", "--algo", "qlearning",
    "--physics", "mjx", "--total-steps", "2000", "--num-envs", "4", "--eval-episodes", "2",
    "--no-video", "--quiet", "--threads", "1",
]  # fmt: skip


class Run(NamedTuple):
    stderr: str
    leaves: list[np.ndarray]
    eval_return: float


def _start(cache: Path, out: Path) -> subprocess.Popen[str]:
    env = {**os.environ, "JAXENVS_CACHE_DIR": str(cache), "PYTHONWARNINGS": "default"}
    return subprocess.Popen(
        [*TRAIN, "--out", str(out)], env=env, text=True,
        stdout=subprocess.PIPE, stderr=subprocess.PIPE,
    )  # fmt: skip


def _finish(proc: subprocess.Popen[str], out: Path) -> Run:
    stdout, stderr = proc.communicate(timeout=600)
    assert proc.returncode == 0, stderr[-3000:]
    summary = json.loads((out / runner.SUMMARY_FILE).read_text())
    leaves = checkpoint.read(out / runner.CHECKPOINT_FILE)[0]
    return Run(stderr, leaves, summary["eval_mean_return"])


def _train(cache: Path, out: Path) -> Run:
    return _finish(_start(cache, out), out)


def _same_result(a: Run, b: Run) -> None:
    assert a.eval_return == b.eval_return
    for x, y in zip(a.leaves, b.leaves, strict=True):
        np.testing.assert_array_equal(x, y)


def _files(cache: Path) -> dict[str, tuple[int, int]]:
    """Every compiled entry: size and modification time."""
    return {p.name: (p.stat().st_size, p.stat().st_mtime_ns) for p in cache.glob("*-cache")}


class Clean(NamedTuple):
    cache: Path  # the directory the clean run used
    template: Path  # a copy of what it left there
    run: Run


@pytest.fixture(scope="module")
def clean(tmp_path_factory) -> Clean:
    """A clean run on a fresh cache directory, and a copy of what it stored. (JAX's keys
    depend on the cache's path, so damaged copies are made at that same path.)"""
    cache = tmp_path_factory.mktemp("clean-cache") / "cache"
    run = _train(cache, tmp_path_factory.mktemp("clean-run") / "run")
    assert JAX_READ_ERROR not in run.stderr, run.stderr
    assert len(_files(cache)) >= 3  # init, chunk and the evaluator, at least
    template = cache.parent / "template"
    shutil.copytree(cache, template)
    return Clean(cache, template, run)


def _damaged_cache_still_trains(clean, tmp_path, damage) -> None:
    """A run on the damaged copy of the clean cache succeeds with the clean run's result
    and JAX says what it could not read; so does the run after it, as JAX keeps the
    damaged entries (each costs a compile, every run)."""
    cache, reference = clean.cache, clean.run
    shutil.rmtree(cache)
    shutil.copytree(clean.template, cache)
    for path in _files_in(cache):
        damage(path)
    damaged = _files(cache)
    for name in ("first", "second"):
        run = _train(cache, tmp_path / name)
        _same_result(run, reference)
        assert JAX_READ_ERROR in run.stderr, run.stderr
        assert all(_files(cache)[k] == v for k, v in damaged.items())


@pytest.mark.full  # three whole MJX training runs in subprocesses
def test_every_entry_with_flipped_bytes(clean, tmp_path):
    _damaged_cache_still_trains(clean, tmp_path, _flip)


@pytest.mark.full
def test_every_entry_truncated(clean, tmp_path):
    _damaged_cache_still_trains(clean, tmp_path, _truncate)


def _files_in(cache: Path) -> list[Path]:
    return [cache / name for name in _files(cache)]


@pytest.mark.full
def test_four_runs_at_once_on_one_fresh_cache(clean, tmp_path):
    reference = clean.run
    cache = tmp_path / "cache"
    outs = [tmp_path / f"run{i}" for i in range(4)]
    procs = [_start(cache, out) for out in outs]
    for proc, out in zip(procs, outs, strict=True):
        run = _finish(proc, out)
        _same_result(run, reference)
        assert JAX_READ_ERROR not in run.stderr, run.stderr
    before = _files(cache)
    after = _train(cache, tmp_path / "after")
    _same_result(after, reference)
    assert JAX_READ_ERROR not in after.stderr, after.stderr
    assert _files(cache) == before  # every entry read, none written again
