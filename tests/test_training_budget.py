"""``total_steps`` and whole chunks: every algorithm rounds up (never trains less than
asked) and the run says so in one line when it rounds."""

from __future__ import annotations

import pytest
from tabular_fakes import fake_envs

from jaxenvs.agents import ppo
from jaxenvs.run import runner


@pytest.fixture(scope="module", autouse=True)
def _fakes():
    with fake_envs():
        yield


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
