"""PPO: hand-computed GAE and loss values, distributions, running statistics, configs, and
a short CartPole-v0 run whose learning signal must move (default tier) and which must
reach a threshold when run longer (full tier)."""

from __future__ import annotations

import dataclasses
import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import jaxenvs
from jaxenvs.agents import losses, ppo
from jaxenvs.agents.base import CHUNK_METRICS, make_train
from jaxenvs.agents.networks import (
    ActorCritic,
    categorical_entropy,
    categorical_log_prob,
    gaussian_entropy,
    gaussian_log_prob,
)
from jaxenvs.config import ConfigError, apply_overrides
from jaxenvs.core import BatchedEnv
from jaxenvs.run import runner

GAMMA, LAM = 0.9, 0.8
REWARDS = jnp.array([1.0, 2.0, 3.0])
VALUES = jnp.array([0.5, 1.0, 1.5])
NEXT_VALUES = jnp.array([1.0, 1.5, 2.0])  # no episode end: next_values[t] = values[t + 1]


def _gae(next_values=NEXT_VALUES, terminated=(0, 0, 0), done=(0, 0, 0)):  # type: ignore[no-untyped-def]
    return losses.gae(
        REWARDS, VALUES, next_values, jnp.array(terminated), jnp.array(done), GAMMA, LAM
    )


# ----------------------------------------------------------------------------- GAE
def test_gae_without_episode_end():
    # deltas: 1 + .9*1 - .5 = 1.4; 2 + .9*1.5 - 1 = 2.35; 3 + .9*2 - 1.5 = 3.3
    # A2 = 3.3; A1 = 2.35 + .72*3.3 = 4.726; A0 = 1.4 + .72*4.726 = 4.80272
    adv, ret = _gae()
    np.testing.assert_allclose(adv, [4.80272, 4.726, 3.3], rtol=1e-6)
    np.testing.assert_allclose(ret, np.array([4.80272, 4.726, 3.3]) + VALUES, rtol=1e-6)


def test_gae_bootstraps_on_truncation_from_the_final_observation():
    # step 1 is truncated; the value of its final_obs is 5.0 (not values[2] = 1.5):
    # delta1 = 2 + .9*5 - 1 = 5.5, and the trace stops: A1 = 5.5; A0 = 1.4 + .72*5.5 = 5.36
    adv, _ = _gae(next_values=jnp.array([1.0, 5.0, 2.0]), done=(0, 1, 0))
    np.testing.assert_allclose(adv, [5.36, 5.5, 3.3], rtol=1e-6)


def test_gae_does_not_bootstrap_on_termination():
    # step 1 terminates: delta1 = 2 - 1 = 1, A1 = 1; A0 = 1.4 + .72*1 = 2.12
    adv, _ = _gae(next_values=jnp.array([1.0, 5.0, 2.0]), terminated=(0, 1, 0), done=(0, 1, 0))
    np.testing.assert_allclose(adv, [2.12, 1.0, 3.3], rtol=1e-6)


def test_gae_batched_envs_are_independent():
    rewards = jnp.stack([REWARDS, 2 * REWARDS], axis=1)  # (T, 2 envs)
    values = jnp.stack([VALUES, VALUES], axis=1)
    nv = jnp.stack([NEXT_VALUES, NEXT_VALUES], axis=1)
    zeros = jnp.zeros((3, 2))
    adv, _ = losses.gae(rewards, values, nv, zeros, zeros, GAMMA, LAM)
    np.testing.assert_allclose(adv[:, 0], _gae()[0], rtol=1e-6)
    single, _ = losses.gae(2 * REWARDS, VALUES, NEXT_VALUES, zeros[:, 0], zeros[:, 0], GAMMA, LAM)
    np.testing.assert_allclose(adv[:, 1], single, rtol=1e-6)


# -------------------------------------------------------------------------- losses


def test_approx_kl_is_zero_for_equal_policies_and_positive_otherwise():
    lp = jnp.array([-0.1, -2.0, -0.7])
    assert float(losses.approx_kl(lp, lp)) == pytest.approx(0.0, abs=1e-7)
    assert float(losses.approx_kl(lp + jnp.array([0.3, -0.2, 0.1]), lp)) > 0.0


def test_normalize_advantages():
    a = losses.normalize_advantages(jnp.array([1.0, 2.0, 3.0, 6.0]))
    assert float(a.mean()) == pytest.approx(0.0, abs=1e-6)
    assert float(a.std()) == pytest.approx(1.0, abs=1e-6)


# ------------------------------------------------------------------- distributions
def test_categorical_log_prob_and_entropy():
    logits = jnp.array([0.0, math.log(3.0)])  # probabilities 0.25, 0.75
    assert float(categorical_log_prob(logits, jnp.array(1))) == pytest.approx(math.log(0.75))
    expected = -(0.25 * math.log(0.25) + 0.75 * math.log(0.75))
    assert float(categorical_entropy(logits)) == pytest.approx(expected, rel=1e-6)


def test_gaussian_log_prob_and_entropy():
    mean, log_std = jnp.zeros(2), jnp.array([0.0, math.log(2.0)])
    # dim 0: N(1; 0, 1); dim 1: N(2; 0, 4) -> both -0.5 - log(std) - 0.5 log(2 pi)
    lp = gaussian_log_prob(mean, log_std, jnp.array([1.0, 2.0]))
    expected = 2 * (-0.5 - 0.5 * math.log(2 * math.pi)) - math.log(2.0)
    assert float(lp) == pytest.approx(expected, rel=1e-6)
    ent = 2 * 0.5 * math.log(2 * math.pi * math.e) + math.log(2.0)
    assert float(gaussian_entropy(log_std)) == pytest.approx(ent, rel=1e-6)


def test_actor_critic_heads_and_initial_policy():
    obs = jnp.ones((7, 3))
    disc = ActorCritic(action_size=4, discrete=True)
    logits, value = disc.apply(disc.init(jax.random.key(0), obs[0]), obs)
    assert logits.shape == (7, 4) and value.shape == (7,)
    # output gain 0.01: the first policy is close to uniform
    assert float(jnp.abs(logits).max()) < 0.1
    cont = ActorCritic(action_size=2, discrete=False, log_std_init=-0.5)
    params = cont.init(jax.random.key(0), obs[0])
    (mean, log_std), value = cont.apply(params, obs)
    assert mean.shape == (7, 2) and value.shape == (7,)
    np.testing.assert_allclose(log_std, -0.5)


# ------------------------------------------------------------------ running stats
def test_running_stats_match_the_whole_stream():
    data = jax.random.normal(jax.random.key(1), (300, 3)) * jnp.array([1.0, 5.0, 0.1]) + 2.0
    stats = ppo.stats_init((3,))
    for batch in jnp.split(data, 6):
        stats = ppo.stats_update(stats, batch)
    np.testing.assert_allclose(stats.mean, data.mean(0), rtol=1e-4)
    np.testing.assert_allclose(stats.var, data.var(0), rtol=1e-3)
    z = ppo.normalize(stats, data, clip=10.0)
    np.testing.assert_allclose(z.mean(0), 0.0, atol=1e-3)


# ------------------------------------------------------------------------ configs
def test_config_validation_names_the_key():
    with pytest.raises(ConfigError, match="num_minibatches"):
        apply_overrides(ppo.PPOConfig(), {"num_envs": 3, "num_steps": 5}, "test")
    with pytest.raises(ConfigError, match="gamma"):
        apply_overrides(ppo.PPOConfig(), {"gamma": 1.5}, "test")


# ------------------------------------------------------------------- training runs
CARTPOLE = ppo.PPOConfig(
    total_steps=4 * 4096,
    num_envs=16,
    num_steps=64,
    updates_per_chunk=4,
    learning_rate=1e-3,
    clip_value=False,
    normalize_obs=False,
    normalize_rewards=True,
)


def _cartpole_run(config):
    env = jaxenvs.make("CartPole-v0")
    trainer = ppo.make_trainer(env, config)
    keys = jax.random.split(jax.random.key(0), 2)
    final, metrics = jax.jit(jax.vmap(make_train(trainer)))(keys)  # one program, 2 seeds
    return env, trainer, final, jax.device_get(metrics)


@pytest.fixture(scope="module")
def cartpole_run():
    """The first 2 chunks (8192 steps) of the run below: one program, 2 seeds."""
    return _cartpole_run(dataclasses.replace(CARTPOLE, total_steps=2 * 4096))


@pytest.mark.full
def test_short_cartpole_run_learns(cartpole_run):
    """The learning signal moves: each update improved its own surrogate objective, the
    policy left the uniform one, and the second chunk's episodes are longer."""
    _, trainer, _, metrics = cartpole_run
    assert set(CHUNK_METRICS) <= set(metrics)
    ret = np.asarray(metrics["mean_return"])  # (seeds, chunks)
    assert ret.shape == (2, trainer.num_chunks) == (2, 2)
    for key in ("mean_return", "loss", "policy_loss", "value_loss", "entropy", "approx_kl"):
        assert np.all(np.isfinite(np.asarray(metrics[key]))), key
    assert np.all(np.asarray(metrics["policy_loss"]) < 0)  # the clipped surrogate went up
    assert np.all(np.asarray(metrics["approx_kl"]) > 0)
    assert np.all(np.asarray(metrics["entropy"])[:, -1] < math.log(2) - 0.02)
    # random play lasts ~22 steps; after 4096 steps of training both seeds play longer
    assert np.all(ret[:, 1] > 1.5 * ret[:, 0]), ret
    np.testing.assert_array_equal(metrics["env_steps"][:, -1], 2 * 4096)


@pytest.mark.full  # training to a threshold
def test_short_cartpole_run_improves():
    _, trainer, _, metrics = _cartpole_run(CARTPOLE)
    assert set(CHUNK_METRICS) <= set(metrics)
    ret = np.asarray(metrics["mean_return"])  # (seeds, chunks)
    assert ret.shape == (2, trainer.num_chunks)
    assert np.all(np.isfinite(ret))
    # random play lasts ~22 steps; after 16k steps both seeds do far better
    assert np.all(ret[:, -1] > 2 * ret[:, 0]), ret
    np.testing.assert_array_equal(metrics["env_steps"][:, -1], CARTPOLE.total_steps)


@pytest.mark.full  # training to the README's threshold
def test_shipped_cartpole_config_solves_cartpole(tmp_path):
    """``jaxenvs train CartPole-v0 --algo ppo`` as the README runs it (the shipped config,
    seed 0): the greedy policy's mean return over 20 episodes is at least 475, the
    task's reward threshold (the shipped config reaches 500: benchmarks/RESULTS.md#ppo)."""
    resolved = runner.resolve_config("CartPole-v0", "ppo", None, train_overrides={"video": False})
    assert resolved.agent.total_steps == 131072  # the shipped file, not a shortened run
    summary = runner.train(resolved, tmp_path, quiet=True)
    assert summary["eval_episodes"] == 20 and not summary["interrupted"]
    assert summary["eval_mean_return"] >= 475.0, summary


def test_greedy_policy_acts_in_the_action_space():
    env = jaxenvs.make("CartPole-v0")
    trainer = ppo.make_trainer(env, dataclasses.replace(CARTPOLE, total_steps=4096))
    params = trainer.policy_params(trainer.init(jax.random.key(0)))
    obs = jax.vmap(env.reset)(jax.random.split(jax.random.key(3), 5)).obs
    act = jax.vmap(trainer.act, in_axes=(None, 0, None))(params, obs, jax.random.key(0))
    assert act.shape == (5,) and act.dtype == jnp.int32
    assert bool(jnp.all((act >= 0) & (act < env.action_size)))


@pytest.mark.full
def test_continuous_randomised_task_chunk_runs():
    env = jaxenvs.make("CartpoleBalance-v0", episode_length=50)
    config = dataclasses.replace(
        CARTPOLE, total_steps=8 * 16, num_envs=8, num_steps=16, updates_per_chunk=1, randomize=True
    )
    trainer = ppo.make_trainer(env, config)
    state = trainer.init(jax.random.key(0))
    # every env drew its own physics (domain randomisation)
    masses = state.env_state.params.model["body_mass"]
    assert masses.shape[0] == 8 and bool(jnp.any(masses[0] != masses[1]))
    state, metrics = jax.jit(trainer.chunk)(state)
    assert int(metrics["env_steps"]) == 128
    for key in ("loss", "entropy", "approx_kl"):
        assert np.isfinite(float(metrics[key])), key
    action = trainer.act(trainer.policy_params(state), state.env_state.obs[0], jax.random.key(1))
    assert action.shape == (1,) and float(jnp.abs(action).max()) <= 1.0


# ----------------------------------------------------------- asymmetric actor-critic
def test_critic_info_feeds_the_critic_alone():
    """``critic_info``: the critic's first layer takes the observation and the named
    metrics, the actor's the observation alone (its params as without them); a state's
    inputs are the metrics of the transition into it, zero at a fresh start, and a
    finished episode's bootstrap reads its last transition's (non-finite ones read as
    zero); a chunk trains with them and updates their statistics at every env step; the
    greedy policy needs none; an unknown key is refused by name."""
    env = jaxenvs.make("CartpoleStayUp-v0", episode_length=3)
    plain = ppo.PPOConfig(
        total_steps=16, num_envs=4, num_steps=4, updates_per_chunk=1, num_minibatches=2,
        actor_hidden=(8,), critic_hidden=(8,),
    )  # fmt: skip
    asym = dataclasses.replace(plain, critic_info=("command",))
    key = jax.random.key(0)
    rs0 = ppo.make_trainer(env, plain).init(key)
    trainer = ppo.make_trainer(env, asym)
    rs = trainer.init(key)
    obs_dim = env.observation_size
    assert rs.params["params"]["critic"]["Dense_0"]["kernel"].shape == (obs_dim + 1, 8)
    assert rs.params["params"]["actor"]["Dense_0"]["kernel"].shape == (obs_dim, 8)
    for a, b in zip(jax.tree.leaves(rs0.params["params"]["actor"]),
                    jax.tree.leaves(rs.params["params"]["actor"]), strict=True):  # fmt: skip
        np.testing.assert_array_equal(a, b)
    assert rs0.critic_stats is None

    benv = BatchedEnv(env, 4)
    state = benv.reset(jax.random.key(1))
    step = jax.jit(benv.step)
    state = step(state, jnp.full((4,), 3, jnp.int32))  # a command away from zero
    last = np.asarray(state.info["command"])
    assert np.all(last != 0)
    np.testing.assert_array_equal(
        ppo.critic_inputs(state.info, ("command",), state.time == 0)[:, 0], last
    )
    state = step(step(state, jnp.full((4,), 3, jnp.int32)), jnp.full((4,), 3, jnp.int32))
    assert np.all(np.asarray(state.time) == 0)  # truncated after 3 steps and reset
    final = ppo.critic_inputs(state.info, ("command",), False)[:, 0]
    assert np.all(np.asarray(final) != 0)  # the bootstrap's: the last transition's
    fresh = ppo.critic_inputs(state.info, ("command",), state.time == 0)
    np.testing.assert_array_equal(fresh, 0.0)  # a fresh start's: zero, as env.reset's

    n0 = float(rs.critic_stats.n)
    rs, metrics = jax.jit(trainer.chunk)(rs)
    assert np.isfinite(float(metrics["value_loss"]))
    assert float(rs.critic_stats.n) == pytest.approx(n0 + 4 * 4)  # every env, every step
    assert float(rs.critic_stats.mean[0]) != 0.0
    bad = {"episode_length": jnp.zeros(2, jnp.int32), "command": jnp.array([jnp.nan, 2.0])}
    np.testing.assert_array_equal(ppo.critic_inputs(bad, ("command",), False)[:, 0], [0, 2])
    act = trainer.act(trainer.policy_params(rs), state.obs[0], jax.random.key(2))
    assert act.shape == () and 0 <= int(act) < env.action_size
    with pytest.raises(ValueError, match="critic_info: nope not among"):
        ppo.make_trainer(env, dataclasses.replace(plain, critic_info=("nope",)))
