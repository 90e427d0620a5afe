"""Stored programs verify themselves: a damaged, truncated or swapped file is discarded
and traced again with one warning, never a failed call or a wrong result."""

from __future__ import annotations

import dataclasses
import json
import os
import shutil
import subprocess
import sys
import warnings
from pathlib import Path
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxenvs.run import checkpoint, program_cache, runner


def _affine(x: jax.Array) -> jax.Array:
    # constants in the module: a flipped byte in one of them would change the result
    return x * jnp.float32(3.25) + jnp.arange(8, dtype=jnp.float32)


def _square(x: jax.Array) -> jax.Array:
    return x * x


X = jnp.linspace(-1.0, 1.0, 8, dtype=jnp.float32)


def _store(directory: Path, fn=_affine, name: str = "affine") -> program_cache.Program:
    return program_cache.load_or_export(fn, (X,), name=name, config={}, directory=directory)


def _only_file(directory: Path, name: str = "affine") -> Path:
    (path,) = directory.glob(f"{name}-*.jaxexport")
    return path


def _damaged_then_healed(directory: Path, fn=_affine, name: str = "affine") -> None:
    """The store, with a damaged file in ``directory``: warns once, returns a program that
    gives the right result, and the next load reads the rebuilt file."""
    with pytest.warns(UserWarning, match="damaged stored program") as record:
        program = _store(directory, fn, name)
    assert len([w for w in record if "damaged" in str(w.message)]) == 1
    assert not program.loaded
    np.testing.assert_array_equal(program.call(X), jax.jit(fn)(X))
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        again = _store(directory, fn, name)
    assert again.loaded
    np.testing.assert_array_equal(again.call(X), jax.jit(fn)(X))


@pytest.mark.parametrize("where", [0, 20, 60, 0.5, -40, -1])
def test_flipped_byte_anywhere_is_caught(tmp_path, where):
    _store(tmp_path)
    path = _only_file(tmp_path)
    blob = bytearray(path.read_bytes())
    i = int(where * len(blob)) if isinstance(where, float) else where
    blob[i] ^= 0x01
    path.write_bytes(bytes(blob))
    _damaged_then_healed(tmp_path)


@pytest.mark.parametrize("keep", [0, 10, 0.5, -1])
def test_truncated_file_is_caught(tmp_path, keep):
    _store(tmp_path)
    path = _only_file(tmp_path)
    blob = path.read_bytes()
    n = int(keep * len(blob)) if isinstance(keep, float) else keep % len(blob)
    path.write_bytes(blob[:n])
    _damaged_then_healed(tmp_path)


def test_file_of_another_key_is_caught(tmp_path):
    """A valid file copied over another key's file (same name prefix, same signature)."""
    _store(tmp_path)
    _store(tmp_path, _square, "square")
    affine, square = _only_file(tmp_path), _only_file(tmp_path, "square")
    square_name = square.name
    square.write_bytes(affine.read_bytes())
    assert (tmp_path / square_name).exists()
    _damaged_then_healed(tmp_path, _square, "square")


def _repack(directory: Path, edit) -> None:
    """Rewrite the stored file with ``edit(module bytes)`` and a valid key and digest, as
    a writer with a bug (not damage on disk) would leave it."""
    path = _only_file(directory)
    key = path.stem.rsplit("-", 1)[1]
    header, module = program_cache._unpack(path.read_bytes(), key)
    path.write_bytes(program_cache._pack(key, header["name"], header["out"], edit(module)))


def test_module_that_does_not_deserialise_is_caught(tmp_path):
    _store(tmp_path)
    _repack(tmp_path, lambda module: module[: len(module) // 2])
    _damaged_then_healed(tmp_path)


def test_stablehlo_that_does_not_deserialise_is_caught(tmp_path):
    """The failure the store once let through to the first call: ``Failed to deserialize
    StableHLO``, raised while lowering, now inside the fallback."""

    def garbage_stablehlo(module: bytes) -> bytes:
        exported = jax.export.deserialize(bytearray(module))
        broken = dataclasses.replace(exported, mlir_module_serialized=b"ML\xefR garbage")
        return bytes(broken.serialize())

    _store(tmp_path)
    _repack(tmp_path, garbage_stablehlo)
    _damaged_then_healed(tmp_path)


def test_file_carries_its_key_and_digest(tmp_path):
    _store(tmp_path)
    path = _only_file(tmp_path)
    key = path.stem.rsplit("-", 1)[1]
    header, _ = program_cache._unpack(path.read_bytes(), key)
    assert header["key"] == key
    with pytest.raises(program_cache.DamagedProgram, match="another key"):
        program_cache._unpack(path.read_bytes(), "0" * 64)


def test_unwritable_store_still_runs(tmp_path):
    blocker = tmp_path / "not-a-dir"
    blocker.write_text("")
    with pytest.warns(UserWarning, match="could not store program"):
        program = _store(blocker / "programs")
    np.testing.assert_array_equal(program.call(X), jax.jit(_affine)(X))


# ------------------------------------------------------- JAX's compile cache, in process
def test_compile_cache_entry_verifies_key_and_content():
    from jaxenvs.run import _jax_cache_hook as hook

    blob = hook.seal("k1", b"executable")
    assert hook.unseal("k1", blob) == b"executable"
    assert hook.unseal("k2", blob) is None  # another key's entry
    assert hook.unseal("k1", blob[:-1]) is None  # truncated
    flipped = bytearray(blob)
    flipped[-3] ^= 1
    assert hook.unseal("k1", bytes(flipped)) is None
    assert hook.unseal("k1", b"executable") is None  # an entry without a digest


def test_verified_cache_removes_a_damaged_entry_and_stores_anew(tmp_path):
    from jaxenvs.run import _jax_cache_hook as hook

    cache = hook.verified_cache(tmp_path, max_size=10**6)
    assert cache.eviction_enabled  # bounded, hence locked
    cache.put("a", b"A" * 100)
    cache.put("b", b"B" * 100)
    assert cache.get("a") == b"A" * 100
    (tmp_path / "a-cache").write_bytes((tmp_path / "b-cache").read_bytes())  # swapped
    with pytest.warns(UserWarning, match="damaged compile-cache entry a"):
        assert cache.get("a") is None
    assert not (tmp_path / "a-cache").exists()
    cache.put("a", b"A" * 100)  # what JAX does after compiling again
    assert cache.get("a") == b"A" * 100


def test_verified_cache_evicts_past_its_size_even_without_access_times(tmp_path):
    from jaxenvs.run import _jax_cache_hook as hook

    (tmp_path / "old-cache").write_bytes(b"x" * 600)  # an unbounded cache's entry
    cache = hook.verified_cache(tmp_path, max_size=1000)
    cache.put("new", b"y" * 500)
    assert not (tmp_path / "old-cache").exists()
    assert cache.get("new") == b"y" * 500


def test_hook_only_on_the_tested_jax_releases(monkeypatch):
    from jaxenvs.run import _jax_cache_hook as hook

    assert hook.jax_release("0.10.2") == (0, 10) and hook.jax_release("0.12.0rc1") == (0, 12)
    for version, tested in (("0.10.2", True), ("0.11.9", True), ("0.12.0", False), ("1.0", False)):
        monkeypatch.setattr(jax, "__version__", version)
        assert hook.supported() is tested


def _compile_fresh(factor: float) -> None:
    # a constant of its own: not in JAX's in-memory cache, so it reaches the file cache
    jax.jit(lambda x: x * factor + 1)(jnp.arange(3.0)).block_until_ready()


def test_enable_bounds_the_cache_and_verifies_its_entries(tmp_path):
    from jaxenvs.run import _jax_cache_hook as hook
    from jaxenvs.run import compile_cache

    assert hook.supported(), f"jax {jax.__version__}: test the fallback below instead"
    # (the conftest's autouse fixture restores the session's cache afterwards)
    assert compile_cache.enable(tmp_path, max_bytes=10**8) == tmp_path
    _compile_fresh(7.0)
    assert (tmp_path / ".lockfile").exists()  # bounded: JAX locks its files
    entries = list(tmp_path.glob("*-cache"))
    assert entries and all(p.read_bytes().startswith(hook.MAGIC) for p in entries)


def test_enable_on_an_untested_jax_uses_its_own_cache(tmp_path, monkeypatch):
    from jaxenvs.run import _jax_cache_hook as hook
    from jaxenvs.run import compile_cache

    monkeypatch.setattr(jax, "__version__", "0.12.0")
    assert compile_cache.enable(tmp_path, max_bytes=10**8) == tmp_path
    _compile_fresh(11.0)
    assert (tmp_path / ".lockfile").exists()  # still bounded and locked
    entries = list(tmp_path.glob("*-cache"))
    assert entries and not any(p.read_bytes().startswith(hook.MAGIC) for p in entries)


def test_unwritable_cache_directory_is_named_once(tmp_path):
    from jaxenvs.run import compile_cache

    blocker = tmp_path / "not-a-dir"
    blocker.write_text("")
    with pytest.warns(UserWarning) as record:
        assert compile_cache.enable(blocker / "cache") is None
    (message,) = [str(w.message) for w in record]
    assert str(blocker / "cache") in message and "compile cold" in message
    assert "\n" not in message
    assert compile_cache.active() is None


# --------------------------------------------- the battery: whole runs on a damaged cache
#: a small run whose every program is stored (MJX physics: the C engine's are not)
TRAIN = [
    sys.executable, "-m", "jaxenvs", "train", "CartPole-v0", "--algo", "qlearning",
    "--physics", "mjx", "--total-steps", "2000", "--num-envs", "4", "--eval-episodes", "2",
    "--no-video", "--quiet", "--threads", "1",
]  # fmt: skip
DAMAGE_WORDS = ("damaged", "Error reading persistent compilation cache")


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
    """Every stored file (programs and compiled entries): size and modification time."""
    return {
        str(p.relative_to(cache)): (p.stat().st_size, p.stat().st_mtime_ns)
        for p in cache.rglob("*")
        if p.is_file() and (p.suffix == ".jaxexport" or p.name.endswith("-cache"))
    }


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
    assert not any(w in run.stderr for w in DAMAGE_WORDS), run.stderr
    assert len(list((cache / "programs").glob("*.jaxexport"))) == 3  # init, chunk, eval
    template = cache.parent / "template"
    shutil.copytree(cache, template)
    return Clean(cache, template, run)


def _flip(path: Path) -> None:
    blob = bytearray(path.read_bytes())
    for i in range(0, len(blob), max(1, len(blob) // 7)):
        blob[i] ^= 0x5A
    path.write_bytes(bytes(blob))


def _truncate(path: Path) -> None:
    path.write_bytes(path.read_bytes()[: path.stat().st_size // 2])


def _swap(cache: Path) -> None:
    """Each stored file gets the content of another key's file of its kind."""
    for kind in ("programs/*.jaxexport", "*-cache"):
        paths = sorted(cache.glob(kind))
        blobs = [p.read_bytes() for p in paths]
        for path, blob in zip(paths, blobs[1:] + blobs[:1], strict=True):
            path.write_bytes(blob)


def _damaged_cache_heals(clean, tmp_path, damage) -> None:
    """A run on the damaged copy of the clean cache succeeds with the clean run's result
    and says what it discarded; the run after it loads what was rebuilt: no warning,
    the same result, and no stored file written again."""
    cache, reference = clean.cache, clean.run
    shutil.rmtree(cache)
    shutil.copytree(clean.template, cache)
    damage(cache)
    healed = _train(cache, tmp_path / "healed")
    _same_result(healed, reference)
    assert "discarding damaged stored program" in healed.stderr, healed.stderr
    assert "discarding damaged compile-cache entry" in healed.stderr, healed.stderr
    # one line per discarded file, and nothing from JAX's own reader (which would mean an
    # unverified entry was read)
    lines = healed.stderr.splitlines()
    assert all(line.startswith("jaxenvs:0: UserWarning: discarding") for line in lines[:-1]), lines
    before = _files(cache)
    after = _train(cache, tmp_path / "after")
    _same_result(after, reference)
    assert not any(w in after.stderr for w in DAMAGE_WORDS), after.stderr
    assert _files(cache) == before  # every program and entry loaded, none rebuilt


@pytest.mark.full  # three whole MJX training runs in subprocesses
def test_every_file_with_flipped_bytes(clean, tmp_path):
    _damaged_cache_heals(clean, tmp_path, lambda c: [_flip(p) for p in _files_in(c)])


@pytest.mark.full
def test_every_file_truncated(clean, tmp_path):
    _damaged_cache_heals(clean, tmp_path, lambda c: [_truncate(p) for p in _files_in(c)])


@pytest.mark.full
def test_files_swapped_between_keys(clean, tmp_path):
    _damaged_cache_heals(clean, tmp_path, _swap)


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
        assert not any(w in run.stderr for w in DAMAGE_WORDS), run.stderr
    before = _files(cache)
    after = _train(cache, tmp_path / "after")
    _same_result(after, reference)
    assert not any(w in after.stderr for w in DAMAGE_WORDS), after.stderr
    assert _files(cache) == before
