"""The tabular agents' bound on their Q-table: a one-line ConfigError naming
``number_splits`` and the size, before anything is allocated or compiled."""

from __future__ import annotations

import dataclasses

import pytest
import yaml

import jaxenvs
from jaxenvs import cli
from jaxenvs.agents import tabular
from jaxenvs.config import ConfigError, apply_overrides
from jaxenvs.run import run_config

BOUNDS = {"obs_low": [-2.4, -3.0, -0.21, -3.5], "obs_high": [2.4, 3.0, 0.21, 3.5]}


@pytest.mark.parametrize("splits", [[1000] * 4, [100] * 4])
def test_a_config_of_too_many_states_is_refused_when_read(splits):
    with pytest.raises(ConfigError) as err:
        apply_overrides(tabular.QLearningConfig(), {"number_splits": splits}, "x.yaml")
    message = str(err.value)
    assert "x.yaml" in message and "'number_splits'" in message
    assert str(splits[0] ** 4) in message
    assert str(tabular.MAX_TABLE_ENTRIES) in message and "\n" not in message


def test_a_table_too_large_for_the_tasks_actions_is_refused_by_the_trainer():
    env = jaxenvs.make("CartPole-v0", physics="c")
    config = apply_overrides(tabular.SarsaConfig(), {"number_splits": 200, **BOUNDS}, "x")
    with pytest.raises(ConfigError, match=r"'number_splits' .* 1600000000 states x 2 actions"):
        tabular.make_trainer(env, config)


def test_a_table_at_the_limit_is_accepted():
    env = jaxenvs.make("CartPole-v0", physics="c")
    splits = [4096, 2048, 1, 1]  # 2**23 states x 2 actions = MAX_TABLE_ENTRIES
    config = apply_overrides(tabular.QLearningConfig(), {"number_splits": splits, **BOUNDS}, "x")
    trainer = tabular.make_trainer(env, config)
    assert trainer.num_chunks >= 1
    with pytest.raises(ConfigError, match="'number_splits'"):
        tabular.make_trainer(env, dataclasses.replace(config, number_splits=4097))


def test_the_command_line_says_it_in_one_line(tmp_path, capsys):
    shipped = yaml.safe_load(run_config.shipped_config("qlearning", "CartPole-v0").read_text())
    shipped["agent"]["number_splits"] = [1000, 1000, 1000, 1000]
    path = tmp_path / "big.yaml"
    path.write_text(yaml.safe_dump(shipped))
    out = tmp_path / "run"
    argv = ["train", "CartPole-v0", "--algo", "qlearning", "--config", str(path)]
    assert cli.main([*argv, "--out", str(out), "--quiet"]) == 2
    err = capsys.readouterr().err.strip()
    assert "number_splits" in err and "1000000000000" in err and "\n" not in err, err
    assert not out.exists()
