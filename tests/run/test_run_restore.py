"""A finished run's policy and evaluation, under its own engine and under the other one."""

from __future__ import annotations

import json

import jax
import numpy as np
import pytest

from jaxenvs import cli
from jaxenvs.run import runner
from jaxenvs.run.checkpoint import CheckpointError

TINY = {
    "qlearning": {"num_envs": 4, "chunk_steps": 100, "total_steps": 400},
    "sarsa": {"num_envs": 4, "chunk_steps": 100, "total_steps": 400},
    "ppo": {
        "num_envs": 4,
        "num_steps": 16,
        "updates_per_chunk": 1,
        "update_epochs": 1,
        "num_minibatches": 1,
        "total_steps": 64,
    },
}


def _train(tmp_path_factory, algo, physics):
    out = tmp_path_factory.mktemp(f"{algo}-{physics}")
    resolved = runner.resolve_config(
        "CartPole-v0", algo, None, TINY[algo], {"eval_episodes": 2, "video": False}
    )
    runner.train(runner.with_physics(resolved, physics), out, quiet=True)
    return out


@pytest.fixture(scope="module")
def c_runs(tmp_path_factory):
    """``c_runs(algo)``: a tiny CartPole run of ``algo`` on the C engine, trained on first use."""
    runs = {}

    def get(algo):
        if algo not in runs:
            runs[algo] = _train(tmp_path_factory, algo, "c")
        return runs[algo]

    return get


@pytest.mark.full
@pytest.mark.parametrize("algo", ["qlearning", "ppo"])
def test_a_c_engine_policy_loads_under_mjx_and_acts_the_same(c_runs, algo):
    _, c_env, c_act = runner.load_policy(c_runs(algo), "c")
    _, mjx_env, mjx_act = runner.load_policy(c_runs(algo), "mjx")
    assert (c_env.physics, mjx_env.physics) == ("c", "mjx")
    obs = jax.random.normal(jax.random.key(1), (32, c_env.observation_size))
    keys = jax.random.split(jax.random.key(2), 32)
    a = jax.vmap(c_act)(obs, keys)
    b = jax.vmap(mjx_act)(obs, keys)
    np.testing.assert_array_equal(np.asarray(a), np.asarray(b))


def test_restore_policy_reads_the_parameters_under_the_runs_engine(c_runs):
    resolved, env, trainer, params = runner.restore_policy(c_runs("qlearning"), "mjx")
    _, _, own_trainer, state = runner.restore(c_runs("qlearning"))
    assert env.physics == "mjx" and resolved.env.physics == "mjx"
    np.testing.assert_array_equal(np.asarray(params), np.asarray(state.q))


@pytest.mark.full
@pytest.mark.parametrize("algo", ["qlearning", "sarsa", "ppo"])
@pytest.mark.parametrize("trained, other", [("c", "mjx"), ("mjx", "c")])
def test_eval_and_render_under_the_other_engine(
    tmp_path_factory, tmp_path, capsys, algo, trained, other
):
    run = _train(tmp_path_factory, algo, trained)
    assert cli.main(["eval", str(run), "--episodes", "2", "--physics", other, "--json"]) == 0
    result = json.loads(capsys.readouterr().out)
    assert result["physics"] == other and result["algo"] == algo
    assert np.isfinite(result["mean_return"])
    video = tmp_path / "policy.mp4"
    argv = ["render", "CartPole-v0", "--policy", str(run), "--out", str(video)]
    assert cli.main([*argv, "--physics", other, "--steps", "10"]) == 0
    assert video.stat().st_size > 0


@pytest.mark.full
def test_a_resume_under_another_engine_names_the_engine(tmp_path_factory, tmp_path):
    run = _train(tmp_path_factory, "qlearning", "c")
    config = (run / runner.CONFIG_FILE).read_text()
    (run / runner.CONFIG_FILE).write_text(config.replace("physics: c", "physics: mjx"))
    with pytest.raises(CheckpointError, match=r"config\.env\.physics is 'c' .* but 'mjx'"):
        runner.train(runner.load_run_config(run), run, resume=True, quiet=True)


@pytest.mark.full
def test_a_run_that_keeps_only_its_policy_evaluates_and_exports_like_the_full_one(c_runs, tmp_path):
    import shutil

    from jaxenvs.deploy import export

    full = c_runs("ppo")
    slim = tmp_path / "slim"
    slim.mkdir()
    for name in (runner.CONFIG_FILE, runner.SUMMARY_FILE):
        shutil.copy(full / name, slim / name)
    shutil.copy(runner.save_policy(full), slim / runner.POLICY_FILE)
    assert not (slim / runner.CHECKPOINT_FILE).exists()

    _, env, act_full = runner.load_policy(full)
    _, _, act_slim = runner.load_policy(slim)
    obs = jax.random.normal(jax.random.key(3), (64, env.observation_size))
    keys = jax.random.split(jax.random.key(4), 64)
    np.testing.assert_array_equal(jax.vmap(act_full)(obs, keys), jax.vmap(act_slim)(obs, keys))
    assert runner.evaluate_run(slim, episodes=2)["episodes"] == 2
    np.testing.assert_array_equal(
        export.policy_of_run(slim)(np.asarray(obs)), export.policy_of_run(full)(np.asarray(obs))
    )
