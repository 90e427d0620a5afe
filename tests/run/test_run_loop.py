"""The training runner: outputs, scores, checkpoints, resume and Ctrl-C, on physics-free tasks."""

from __future__ import annotations

import io
import json
import struct
import zipfile

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from tabular_fakes import fake_envs

from jaxenvs.agents import ppo
from jaxenvs.config import config_to_dict
from jaxenvs.run import checkpoint, loop, runner
from jaxenvs.run.checkpoint import CheckpointError

METRIC_COLUMNS = ("chunk", "seed", "env_steps", "episodes", "mean_return", "max_return")


@pytest.fixture(scope="module", autouse=True)
def _fakes():
    with fake_envs():
        yield


def _chain_config(**train):
    agent = dict(
        alpha=0.5,
        gamma=0.9,
        epsilon=1.0,
        epsilon_discount=0.95,
        number_splits=7,
        obs_low=[0.0],
        obs_high=[7.0],
        num_envs=2,
        chunk_steps=30,
        total_steps=2 * 30 * 4,  # 4 chunks
    )
    run = dict(num_seeds=2, eval_episodes=3, video=False, **train)
    return runner.resolve_config("Test-Chain-v0", "qlearning", None, agent, run)


def _leaves(run_dir):
    return checkpoint.read(run_dir / runner.CHECKPOINT_FILE)[0]


def _progress(run_dir):
    rows = runner.read_progress(run_dir / runner.PROGRESS_FILE)
    return [tuple(r[c] for c in METRIC_COLUMNS) for r in rows]


@pytest.fixture(scope="module")
def full_run(tmp_path_factory):
    out = tmp_path_factory.mktemp("full")
    summary = runner.train(_chain_config(), out, quiet=True)
    return out, summary


def test_outputs_and_summary(full_run):
    out, summary = full_run
    for name in ("config.yaml", "progress.csv", "summary.json", "checkpoint.npz"):
        assert (out / name).is_file(), name
    assert (out / "learning_curve.png").stat().st_size > 1000
    on_disk = json.loads((out / "summary.json").read_text())
    assert on_disk["eval_mean_return"] == summary["eval_mean_return"]
    assert summary["chunks"] == summary["num_chunks"] == 4 and summary["finished"]
    assert summary["env_steps"] == 2 * 240  # two seeds
    assert summary["eval_episodes"] == 6
    # the chain pays 1 at the goal: a learned greedy policy gets there every time
    assert summary["eval_mean_return"] == 1.0
    rows = runner.read_progress(out / "progress.csv")
    assert len(rows) == 8 and {r["seed"] for r in rows} == {"0", "1"}
    assert "epsilon" in rows[0]
    # overall score = mean length over training episodes, recomputed from the rows
    for k in range(2):
        mine = [r for r in rows if r["seed"] == str(k)]
        total = sum(float(r["sum_length"]) for r in mine)
        eps = int(mine[-1]["episodes"])
        assert summary["overall_score_per_seed"][k] == pytest.approx(total / eps, rel=1e-5)
        assert 6 <= summary["best_100_score_per_seed"][k] <= 12


def test_ctrl_c_leaves_a_valid_checkpoint_and_results(full_run, tmp_path, monkeypatch):
    out_a, summary_a = full_run
    out = tmp_path / "c"
    calls = {"n": 0}
    real_write = loop.write_progress

    def interrupt_on_third(*args):
        calls["n"] += 1
        if calls["n"] == 3:  # chunk 3 computed, checkpoint still at chunk 2
            raise KeyboardInterrupt
        real_write(*args)

    monkeypatch.setattr(loop, "write_progress", interrupt_on_third)
    with pytest.raises(KeyboardInterrupt):
        runner.train(_chain_config(), out, quiet=True)
    summary = json.loads((out / "summary.json").read_text())
    assert summary["interrupted"] and summary["chunks"] == 2
    monkeypatch.setattr(loop, "write_progress", real_write)
    final = runner.train(runner.load_run_config(out), out, resume=True, quiet=True)
    for a, b in zip(_leaves(out_a), _leaves(out), strict=True):
        np.testing.assert_array_equal(a, b)
    assert final["eval_mean_return"] == summary_a["eval_mean_return"]
    assert _progress(out_a) == _progress(out)


def test_corrupt_or_truncated_checkpoint_is_refused(full_run, tmp_path):
    out_a, _ = full_run
    data = (out_a / "checkpoint.npz").read_bytes()
    template = jax.eval_shape(lambda: runner.restore(out_a)[3])
    truncated = tmp_path / "truncated.npz"
    truncated.write_bytes(data[: len(data) // 2])
    with pytest.raises(CheckpointError, match="truncated"):
        checkpoint.load(truncated, template)
    # a flipped byte inside the Q-table's stored data (the zip CRC catches it)
    with zipfile.ZipFile(io.BytesIO(data)) as z:
        info = z.getinfo("leaf_00000.npy")
    name_len, extra_len = struct.unpack(
        "<HH", data[info.header_offset + 26 : info.header_offset + 30]
    )
    start = info.header_offset + 30 + name_len + extra_len
    flipped = bytearray(data)
    flipped[start + info.compress_size - 3] ^= 0xFF
    corrupt = tmp_path / "corrupt.npz"
    corrupt.write_bytes(bytes(flipped))
    with pytest.raises(CheckpointError, match="corrupt"):
        checkpoint.load(corrupt, template)
    # a consistent zip whose arrays no longer match the stored checksum
    with np.load(out_a / "checkpoint.npz", allow_pickle=False) as npz:
        arrays = {k: npz[k] for k in npz.files}
    arrays["leaf_00000"] = arrays["leaf_00000"] + 1.0
    tampered = tmp_path / "tampered.npz"
    np.savez(tampered, **arrays)
    with pytest.raises(CheckpointError, match="checksum mismatch"):
        checkpoint.load(tampered, template)
    with pytest.raises(CheckpointError, match="no checkpoint"):
        checkpoint.load(tmp_path / "missing.npz", template)


def test_checkpoint_of_another_config_is_refused(full_run, tmp_path):
    out_a, _ = full_run
    other = _chain_config()
    bigger = runner.resolve_config(
        "Test-Chain-v0", "qlearning", None, {**config_to_dict(other.agent), "num_envs": 3}
    )
    env, trainer = runner.build(bigger)
    template = jax.eval_shape(jax.vmap(trainer.init), runner.seed_keys(0, 2))
    with pytest.raises(CheckpointError, match="different"):
        checkpoint.load(out_a / "checkpoint.npz", template)


def test_checkpoint_round_trip_keeps_prng_keys(tmp_path):
    state = {
        "key": jax.random.split(jax.random.key(3), 2),
        "raw": jax.random.PRNGKey(4),
        "x": jnp.arange(5.0),
        "n": jnp.int32(7),
    }
    path = tmp_path / "ck.npz"
    checkpoint.save(path, state, {"chunk": 3})
    restored, meta = checkpoint.load(path, jax.eval_shape(lambda: state))
    assert meta == {"chunk": 3}
    np.testing.assert_array_equal(
        jax.random.key_data(restored["key"]), jax.random.key_data(state["key"])
    )
    np.testing.assert_array_equal(restored["raw"], state["raw"])
    np.testing.assert_array_equal(restored["x"], state["x"])
    assert [p.name for p in tmp_path.iterdir()] == ["ck.npz"]  # the temp file was renamed away


def test_load_policy_acts_greedily(full_run):
    out_a, _ = full_run
    env_id, env, act = runner.load_policy(out_a)
    assert env_id == "Test-Chain-v0" and env.discrete
    actions = [int(act(jnp.array([x + 0.5]), jax.random.key(x))) for x in range(6)]
    assert actions == [1] * 6


def test_evaluate_run(full_run):
    out_a, _ = full_run
    result = runner.evaluate_run(out_a, episodes=4)
    assert result["episodes"] == 8 and result["mean_return"] == 1.0


# ------------------------------------------------- total_steps in whole chunks


@pytest.mark.parametrize("total, chunks", [(1, 1), (64, 1), (65, 2), (100, 2), (128, 2)])
def test_ppo_rounds_up_to_whole_chunks(total, chunks):
    config = ppo.PPOConfig(total_steps=total, num_envs=4, num_steps=16, updates_per_chunk=1)
    assert config.steps_per_chunk == 64
    assert config.num_chunks == chunks


def test_every_algorithm_rounds_the_same_way():
    agent = {"number_splits": 7, "obs_low": [0.0], "obs_high": [7.0], "num_envs": 2}
    agent.update(chunk_steps=32, total_steps=65)
    _, tab_trainer = runner.build(runner.resolve_config("Test-Chain-v0", "qlearning", None, agent))
    ppo_config = ppo.PPOConfig(total_steps=65, num_envs=2, num_steps=32, updates_per_chunk=1)
    assert tab_trainer.steps_per_chunk == ppo_config.steps_per_chunk == 64
    assert tab_trainer.num_chunks == ppo_config.num_chunks == 2


@pytest.mark.full
def test_the_run_names_the_steps_it_will_take(tmp_path):
    agent = {
        "number_splits": 7,
        "obs_low": [0.0],
        "obs_high": [7.0],
        "num_envs": 2,
        "chunk_steps": 30,
        "total_steps": 100,
    }
    resolved = runner.resolve_config(
        "Test-Chain-v0", "qlearning", None, agent, {"eval_episodes": 1, "video": False}
    )
    notices: list[str] = []
    summary = runner.train(resolved, tmp_path / "run", log=notices.append)
    line = "total_steps 100 rounds up to whole chunks: 120 env steps per seed (2 chunks of 60)"
    assert line in notices, notices
    assert summary["env_steps"] == 120
    exact = runner.resolve_config(
        "Test-Chain-v0", "qlearning", None, {**agent, "total_steps": 120}, {"video": False}
    )
    notices.clear()
    runner.train(exact, tmp_path / "exact", log=notices.append)
    assert not any("rounds up" in n for n in notices), notices


def test_preload_plotting_imports_pyplot_on_agg_and_stays_quiet_on_failure(monkeypatch, capfd):
    import sys

    import matplotlib

    from jaxenvs.run import results

    results.preload_plotting().join(timeout=60)

    assert matplotlib.get_backend().lower() == "agg"
    assert "matplotlib.pyplot" in sys.modules

    called: list[str] = []  # the thread itself imports (pyplot may be in sys.modules already)
    monkeypatch.setattr(results, "agg_pyplot", lambda: called.append("pyplot"))
    results.preload_plotting().join(timeout=60)
    assert called == ["pyplot"]

    def broken() -> None:
        raise ImportError("no matplotlib here")

    monkeypatch.setattr(results, "agg_pyplot", broken)
    thread = results.preload_plotting()
    thread.join(timeout=60)
    assert not thread.is_alive()
    assert "no matplotlib here" not in capfd.readouterr().err  # plot_curves reports it
