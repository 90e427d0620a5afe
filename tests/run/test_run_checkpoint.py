"""Checkpoints: the checksum covers the metadata, every malformed file is one
:class:`CheckpointError` (one line from the command line), and a resume refuses a
checkpoint of another env, algorithm or config, naming what differs."""

from __future__ import annotations

import io
import json
import os
import re
import shutil
import signal
from collections.abc import Callable
from pathlib import Path
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from tabular_fakes import fake_envs

from jaxenvs import cli, files
from jaxenvs.run import checkpoint, loop, runner
from jaxenvs.run.checkpoint import CheckpointError

REPO = Path(__file__).resolve().parents[2]


@pytest.fixture(scope="module", autouse=True)
def _fakes():
    with fake_envs():
        yield


def _chain(alpha: float = 0.5):
    agent = dict(
        alpha=alpha, gamma=0.9, number_splits=7, obs_low=[0.0], obs_high=[7.0],
        num_envs=2, chunk_steps=30, total_steps=2 * 30 * 3,
    )  # fmt: skip
    return runner.resolve_config(
        "Test-Chain-v0", "qlearning", None, agent, dict(eval_episodes=2, video=False)
    )


@pytest.fixture(scope="module")
def run_dir(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("run")
    runner.train(_chain(), out, quiet=True, max_chunks=1)
    return out


def _arrays(path: Path) -> dict[str, np.ndarray]:
    with np.load(path, allow_pickle=False) as npz:
        return {k: npz[k] for k in npz.files}


def _rewrite(src: Path, dst: Path, edit: Callable[[dict[str, Any]], Any], sign: bool) -> None:
    """Copy checkpoint ``src`` to ``dst`` with its metadata record edited by ``edit``
    (which returns the new record); ``sign`` recomputes a valid checksum, as a careful
    forger or a buggy writer would."""
    arrays = _arrays(src)
    meta = json.loads(arrays.pop(checkpoint.META_KEY).tobytes().decode())
    new = edit(meta)
    if sign and isinstance(new, dict):
        new["sha256"] = checkpoint._digest(arrays, new)
    arrays[checkpoint.META_KEY] = np.frombuffer(json.dumps(new).encode(), np.uint8)
    buf = io.BytesIO()
    np.savez(buf, **arrays)
    dst.write_bytes(buf.getvalue())


def _set(meta: dict[str, Any], path: tuple[str, ...], value: Any) -> dict[str, Any]:
    node = meta
    for k in path[:-1]:
        node = node[k]
    if value is KeyError:
        del node[path[-1]]
    else:
        node[path[-1]] = value
    return meta


@pytest.mark.full
def test_edited_metadata_fails_the_checksum(run_dir, tmp_path):
    edited = tmp_path / "edited.npz"
    _rewrite(run_dir / runner.CHECKPOINT_FILE, edited,
             lambda m: _set(m, ("metadata", "chunk"), 3), sign=False)  # fmt: skip
    with pytest.raises(CheckpointError, match="checksum mismatch"):
        checkpoint.read(edited)


MALFORMED = {
    "no num_leaves": lambda m: _set(m, ("num_leaves",), KeyError),
    "num_leaves a string": lambda m: _set(m, ("num_leaves",), "4"),
    "leaves not a list": lambda m: _set(m, ("leaves",), {}),
    "a leaf record without key_impl": lambda m: _set(m, ("leaves", 0, "key_impl"), KeyError),
    "metadata not a mapping": lambda m: _set(m, ("metadata",), [1]),
    "the record a list": lambda m: [m],
    "an unknown PRNG implementation": lambda m: m,  # edited below: see the test
}


@pytest.mark.parametrize("what", sorted(MALFORMED))
def test_every_malformed_record_is_a_checkpoint_error(run_dir, tmp_path, what):
    src = run_dir / runner.CHECKPOINT_FILE
    bad = tmp_path / "bad.npz"
    edit = MALFORMED[what]
    if what == "an unknown PRNG implementation":
        _, meta = checkpoint.read(src)
        i = next(i for i, info in enumerate(meta["leaves"]) if info["key_impl"])

        def edit(m):
            return _set(m, ("leaves", i, "key_impl"), "no-such-prng")

    _rewrite(src, bad, edit, sign=True)
    template = jax.eval_shape(lambda: runner.restore(run_dir)[3])
    with pytest.raises(CheckpointError, match=str(bad)) as err:
        checkpoint.load(bad, template)
    assert "\n" not in str(err.value)


@pytest.mark.parametrize("damage", ["truncated", "empty", "not a zip", "no metadata"])
def test_eval_of_a_damaged_checkpoint_is_one_line(run_dir, tmp_path, capsys, damage):
    run = tmp_path / "run"
    shutil.copytree(run_dir, run)
    path = run / runner.CHECKPOINT_FILE
    data = path.read_bytes()
    if damage == "truncated":
        path.write_bytes(data[: len(data) // 2])
    elif damage == "empty":
        path.write_bytes(b"")
    elif damage == "not a zip":
        path.write_text("hello")
    else:
        arrays = _arrays(path)
        del arrays[checkpoint.META_KEY]
        np.savez(path, **arrays)
    assert cli.main(["eval", str(run), "--episodes", "1"]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("jaxenvs eval: error:") and str(path) in err, err
    assert "\n" not in err and "Traceback" not in err


@pytest.mark.full
def test_resume_refuses_a_checkpoint_of_another_config(run_dir, tmp_path, capsys):
    other = tmp_path / "other"
    runner.train(_chain(alpha=0.25), other, quiet=True, max_chunks=1)
    shutil.copy(run_dir / runner.CHECKPOINT_FILE, other / runner.CHECKPOINT_FILE)
    with pytest.raises(CheckpointError, match=r"config\.agent\.alpha is 0\.5 .* but 0\.25"):
        runner.train(runner.load_run_config(other), other, resume=True, quiet=True)
    assert cli.main(["train", "--resume", str(other), "--quiet"]) == 2
    err = capsys.readouterr().err.strip()
    assert "config.agent.alpha" in err and "\n" not in err, err


def test_resume_refuses_another_env_or_algorithm(tmp_path):
    stored = {"env_id": "CartPole-v0", "algo": "ppo", "config": {"agent": {"alpha": 1}}}
    expected = {"env_id": "Test-Chain-v0", "algo": "qlearning", "config": {"agent": {}}}
    with pytest.raises(CheckpointError) as err:
        checkpoint.check_matches(tmp_path / "c.npz", stored, expected)
    message = str(err.value)
    for name in ("env_id is 'CartPole-v0'", "algo is 'ppo'", "config.agent.alpha is missing"):
        assert name in message, message
    checkpoint.check_matches(tmp_path / "c.npz", expected, expected)  # no error


def test_a_matching_resume_still_works(run_dir, tmp_path):
    run = tmp_path / "run"
    shutil.copytree(run_dir, run)
    summary = runner.train(runner.load_run_config(run), run, resume=True, quiet=True)
    assert summary["chunks"] == 3 and not summary["interrupted"]


# ----------------------------------------------------------------------------- Ctrl-C
def test_ctrl_c_commits_the_running_chunk_then_stops(tmp_path, monkeypatch):
    """A real SIGINT while chunk 2 runs: chunk 2 is finished and committed (progress,
    checkpoint), the notice says how to resume, and the resumed run ends where an
    uninterrupted one does."""
    whole = runner.train(_chain(), tmp_path / "whole", quiet=True)
    before = signal.getsignal(signal.SIGINT)  # SIG_IGN where the shell started us in the background
    real = loop._run_chunk
    calls = {"n": 0}

    def interrupted_during_second(run, clock, rs):
        calls["n"] += 1
        if calls["n"] == 2:
            signal.raise_signal(signal.SIGINT)  # handled when Python next runs: mid-chunk
        return real(run, clock, rs)

    monkeypatch.setattr(loop, "_run_chunk", interrupted_during_second)
    notices: list[str] = []
    out = tmp_path / "stopped"
    with pytest.raises(KeyboardInterrupt):
        runner.train(_chain(), out, log=notices.append)
    assert calls["n"] == 2  # no chunk started after the request
    _, meta = checkpoint.read(out / runner.CHECKPOINT_FILE)
    assert meta["metadata"]["chunk"] == 2
    assert {int(r["chunk"]) for r in runner.read_progress(out / runner.PROGRESS_FILE)} == {0, 1}
    summary = json.loads((out / runner.SUMMARY_FILE).read_text())
    assert summary["interrupted"] and summary["chunks"] == 2
    assert any("stopping after the running chunk" in n for n in notices), notices
    assert any(f"jaxenvs train --resume {out}" in n for n in notices), notices
    assert signal.getsignal(signal.SIGINT) is before  # restored
    monkeypatch.setattr(loop, "_run_chunk", real)
    resumed = runner.train(runner.load_run_config(out), out, resume=True, quiet=True)
    assert resumed["eval_mean_return"] == whole["eval_mean_return"]
    stopped_leaves, whole_leaves = (
        checkpoint.read(d / runner.CHECKPOINT_FILE)[0] for d in (out, tmp_path / "whole")
    )
    for a, b in zip(stopped_leaves, whole_leaves, strict=True):
        np.testing.assert_array_equal(a, b)


@pytest.fixture()
def saved(tmp_path):
    state = {"w": jnp.arange(6.0).reshape(2, 3), "key": jax.random.key(1), "n": jnp.int32(4)}
    path = tmp_path / "ck.npz"
    checkpoint.save(path, state, {"chunk": 1})
    return path, state


def test_checkpoint_write_is_atomic(saved, monkeypatch):
    """A crash (or Ctrl-C) during the rename keeps the old file and leaves no temp file."""
    path, state = saved
    before = path.read_bytes()

    def crash(src, dst):
        raise KeyboardInterrupt

    monkeypatch.setattr(files.os, "replace", crash)  # the rename every atomic write ends with
    newer = {**state, "w": state["w"] + 100.0}
    with pytest.raises(KeyboardInterrupt):
        checkpoint.save(path, newer, {"chunk": 2})
    assert path.read_bytes() == before
    assert sorted(p.name for p in path.parent.iterdir()) == [path.name]
    restored, meta = checkpoint.load(path, jax.eval_shape(lambda: state))
    assert meta == {"chunk": 1}
    np.testing.assert_array_equal(restored["w"], state["w"])


def test_checkpoint_is_versioned_and_other_versions_are_refused(saved, tmp_path):
    path, state = saved
    with np.load(path, allow_pickle=False) as npz:
        arrays = {k: npz[k] for k in npz.files}
    meta = json.loads(arrays["__meta__"].tobytes())
    assert meta["format"] == "jaxenvs-checkpoint" and meta["version"] == checkpoint.FORMAT_VERSION
    assert re.fullmatch(r"[0-9a-f]{64}", meta["sha256"])
    assert all(a.dtype != object for a in arrays.values())
    meta["version"] = checkpoint.FORMAT_VERSION + 1
    arrays["__meta__"] = np.frombuffer(json.dumps(meta).encode(), np.uint8)
    future = tmp_path / "future.npz"
    np.savez(future, **arrays)
    with pytest.raises(CheckpointError, match=rf"future\.npz.*version {meta['version']} is not"):
        checkpoint.load(future, jax.eval_shape(lambda: state))
    garbage = tmp_path / "garbage.npz"
    garbage.write_bytes(os.urandom(512))
    with pytest.raises(CheckpointError, match="garbage.npz.*truncated or corrupt"):
        checkpoint.load(garbage, jax.eval_shape(lambda: state))
    empty = tmp_path / "empty.npz"
    empty.write_bytes(b"")
    with pytest.raises(CheckpointError, match="empty.npz"):
        checkpoint.read(empty)


def test_no_pickle_anywhere_in_the_package():
    pattern = re.compile(
        r"^\s*(import|from)\s+(pickle|cPickle|cloudpickle|dill|joblib|shelve)\b"
        r"|allow_pickle\s*=\s*True|torch\.(save|load)\b",
        re.M,
    )
    offenders = [
        f"{p.relative_to(REPO)}: {m.group(0).strip()}"
        for p in sorted((REPO / "jaxenvs").rglob("*.py"))
        for m in pattern.finditer(p.read_text())
    ]
    assert not offenders, offenders
    assert "allow_pickle=False" in (REPO / "jaxenvs/run/checkpoint.py").read_text()
