"""Tabular Q-learning / SARSA: hand-computed updates, schedule, binning, bootstrapping."""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import pytest
import yaml
from tabular_fakes import Chain, ChainConfig, OneState, OneStateConfig

import jaxenvs
from jaxenvs import cli
from jaxenvs.agents import tabular
from jaxenvs.agents import tabular as T
from jaxenvs.config import ConfigError, apply_overrides
from jaxenvs.run import run_config


def _config(cls=T.QLearningConfig, **kw):
    base = dict(obs_low=(-1.0,), obs_high=(1.0,), number_splits=1, num_envs=2, chunk_steps=50)
    base.update(kw)
    return cls(**base)


# ---------------------------------------------------------------- pure update functions
def test_q_learning_update_by_hand():
    # Q(s=0) = [1, 2], Q(s'=1) = [3, 0.5]; r = 1, gamma = 0.9, alpha = 0.5, a = 0:
    # target = 1 + 0.9 * max(3, 0.5) = 3.7, delta = 2.7, Q(0, 0) = 1 + 0.5 * 2.7 = 2.35
    q = jnp.array([[1.0, 2.0], [3.0, 0.5]])
    s, a, s_next = jnp.array([0]), jnp.array([0]), jnp.array([1])
    boot = T.q_learning_bootstrap(q, s_next)
    delta = T.td_errors(q, s, a, jnp.array([1.0]), jnp.array([False]), boot, 0.9)
    np.testing.assert_allclose(delta, [2.7], rtol=1e-6)
    new = T.shared_update(q, s, a, delta, jnp.array([True]), 0.5)
    np.testing.assert_allclose(new, [[2.35, 2.0], [3.0, 0.5]], rtol=1e-6)


def test_sarsa_update_by_hand():
    # same transition, but the next action actually taken is a' = 1:
    # target = 1 + 0.9 * Q(1, 1) = 1.45, delta = 0.45, Q(0, 0) = 1 + 0.5 * 0.45 = 1.225
    q = jnp.array([[1.0, 2.0], [3.0, 0.5]])
    s, a, s_next, a_next = jnp.array([0]), jnp.array([0]), jnp.array([1]), jnp.array([1])
    boot = q[s_next, a_next]
    delta = T.td_errors(q, s, a, jnp.array([1.0]), jnp.array([False]), boot, 0.9)
    new = T.shared_update(q, s, a, delta, jnp.array([True]), 0.5)
    np.testing.assert_allclose(new[0, 0], 1.225, rtol=1e-6)


def test_terminal_target_does_not_bootstrap():
    q = jnp.array([[1.0, 2.0], [3.0, 0.5]])
    boot = T.q_learning_bootstrap(q, jnp.array([1]))
    delta = T.td_errors(
        q, jnp.array([0]), jnp.array([0]), jnp.array([1.0]), jnp.array([True]), boot, 0.9
    )
    np.testing.assert_allclose(delta, [0.0])  # target = r = 1 = Q(0, 0)


def test_simultaneous_updates_of_one_entry_average():
    q = jnp.zeros((2, 2))
    s, a = jnp.array([0, 0, 1, 0]), jnp.array([1, 1, 0, 1])
    delta = jnp.array([1.0, 3.0, 4.0, 100.0])
    mask = jnp.array([True, True, True, False])  # the 4th env does not learn
    new = T.shared_update(q, s, a, delta, mask, 0.5)
    np.testing.assert_allclose(new, [[0.0, 0.5 * 2.0], [0.5 * 4.0, 0.0]])


def test_epsilon_schedule_per_episode_with_floor():
    cfg = _config(epsilon=1.0, epsilon_discount=0.9, epsilon_min=0.05)
    eps = T.epsilon_at(cfg, jnp.array([0, 1, 2, 10, 1000]))
    np.testing.assert_allclose(eps, [1.0, 0.9, 0.81, 0.9**10, 0.05], rtol=1e-5)


def test_binning_at_the_edges():
    disc = T.make_discretiser((-1.0, 0.0), (1.0, 10.0), (4, 5))
    cases = {
        (-5.0, 0.0): (0, 0),  # below the bound: edge bin
        (-1.0, -3.0): (0, 0),
        (-0.51, 1.99): (0, 0),
        (-0.5, 2.0): (1, 1),
        (0.99, 9.99): (3, 4),
        (1.0, 10.0): (3, 4),  # on the upper bound: last bin
        (7.0, 1e6): (3, 4),  # above: edge bin
    }
    for obs, bins in cases.items():
        got = T.bin_index(disc, jnp.array(obs, jnp.float32))
        assert tuple(np.asarray(got)) == bins, (obs, got)
        assert int(T.state_index(disc, jnp.array(obs, jnp.float32))) == bins[0] * 5 + bins[1]
    assert disc.num_states == 20


@pytest.mark.full
def test_greedy_breaks_ties_at_random():
    row = jnp.array([1.0, 1.0, 0.0])
    picks = jax.vmap(lambda k: T.greedy_action(row, k))(jax.random.split(jax.random.key(0), 200))
    assert set(np.asarray(picks).tolist()) == {0, 1}
    explore = jax.vmap(lambda k: T.epsilon_greedy(row, jnp.float32(1.0), k))(
        jax.random.split(jax.random.key(1), 300)
    )
    assert set(np.asarray(explore).tolist()) == {0, 1, 2}


def test_bad_values_are_named():
    with pytest.raises(ConfigError, match="'alpha'"):
        apply_overrides(T.QLearningConfig(), {"alpha": -0.1}, "x.yaml")
    with pytest.raises(ConfigError, match="'number_splits'"):
        apply_overrides(T.QLearningConfig(), {"number_splits": 0}, "x.yaml")
    with pytest.raises(ConfigError, match="'number_splits'"):
        apply_overrides(T.QLearningConfig(), {"number_splits": [3, 0]}, "x.yaml")


def test_continuous_task_is_refused():
    env = jaxenvs.make("CartpoleBalance-v0")
    with pytest.raises(ConfigError, match="discrete-action"):
        T.make_trainer(env, _config(obs_low=(-1.0,) * 5, obs_high=(1.0,) * 5))


# ------------------------------------------------------- the trainer on physics-free tasks
def _train(env, cfg, chunks, seed=0):
    trainer = T.make_trainer(env, cfg)
    chunk = jax.jit(trainer.chunk)
    state = jax.jit(trainer.init)(jax.random.key(seed))
    metrics = []
    for _ in range(chunks):
        state, m = chunk(state)
        metrics.append(jax.device_get(m))
    return trainer, state, metrics


@pytest.mark.parametrize("cls", [T.QLearningConfig, T.SarsaConfig])
@pytest.mark.parametrize("terminate, expected", [(True, 1.0), (False, 2.0)])
def test_terminal_vs_truncated_bootstrap(cls, terminate, expected):
    # every episode is one step with reward 1; gamma 0.5. Terminal: Q -> 1. Truncated:
    # bootstraps from final_obs, Q -> 1 / (1 - 0.5) = 2.
    env = OneState(OneStateConfig(episode_length=1, terminate=terminate))
    cfg = _config(cls, gamma=0.5, alpha=0.5, epsilon=0.5, epsilon_discount=1.0)
    _, state, metrics = _train(env, cfg, 1)
    np.testing.assert_allclose(state.q, expected * np.ones((1, 2)), rtol=1e-4)
    assert metrics[0]["episodes"] == 2 * 50
    assert metrics[0]["mean_length"] == 1.0


@pytest.mark.full
def test_each_env_counts_its_own_episodes():
    env = OneState(OneStateConfig(episode_length=1))
    cfg = _config(num_envs=3, chunk_steps=7, epsilon_discount=0.9, epsilon_min=0.0)
    _, state, metrics = _train(env, cfg, 2)
    np.testing.assert_array_equal(state.episodes, [14, 14, 14])
    np.testing.assert_allclose(metrics[-1]["epsilon"], 0.9**14, rtol=1e-5)
    assert metrics[-1]["env_steps"] == 42


@pytest.mark.full
def test_episodes_per_env_stops_learning():
    env = OneState(OneStateConfig(episode_length=1))
    cfg = _config(num_envs=2, chunk_steps=5, episodes_per_env=3)
    _, state, metrics = _train(env, cfg, 2)
    np.testing.assert_array_equal(state.episodes, [3, 3])
    assert metrics[0]["active_envs"] == 0 and metrics[0]["episodes_in_chunk"] == 6
    assert metrics[1]["episodes_in_chunk"] == 0 and metrics[1]["env_steps"] == 6


@pytest.mark.parametrize("cls", [T.QLearningConfig, T.SarsaConfig])
def test_learns_the_chain(cls):
    env = Chain(ChainConfig(episode_length=12, length=6))
    cfg = cls(
        alpha=0.5,
        gamma=0.9,
        epsilon=1.0,
        epsilon_discount=0.98,
        number_splits=7,
        obs_low=(0.0,),
        obs_high=(7.0,),
        num_envs=4,
        chunk_steps=200,
    )
    trainer, state, metrics = _train(env, cfg, 3)
    # greedy from every non-goal state goes right
    actions = [int(trainer.act(state.q, jnp.array([x + 0.5]), jax.random.key(x))) for x in range(6)]
    assert actions == [1] * 6
    assert metrics[-1]["mean_return"] > metrics[0]["mean_return"]


# ------------------------------------------------------------ the real task, one compile
@pytest.mark.full  # training to a threshold; the learning itself: test_learns_the_chain
def test_short_cartpole_run_improves_over_random():
    env = jaxenvs.make("CartPole-v0")
    cfg = T.QLearningConfig(
        alpha=0.1,
        gamma=0.99,
        epsilon=1.0,
        epsilon_discount=0.97,
        number_splits=(1, 1, 6, 6),
        obs_low=(-2.4, -3.0, -0.21, -3.0),
        obs_high=(2.4, 3.0, 0.21, 3.0),
        num_envs=8,
        chunk_steps=500,
    )
    _, _, metrics = _train(env, cfg, 6)
    first, last = metrics[0]["mean_return"], metrics[-1]["mean_return"]
    # a uniformly random policy averages about 22 on CartPole; epsilon starts at 1
    assert first < 35
    assert last > 2 * first, (first, last)


# ------------------------------------------------- the Q-table's bound


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
