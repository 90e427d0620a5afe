"""The Brax adapter (jaxenvs.compat.brax): Brax's Env interface, its training wrappers'
view of termination and truncation, and a Brax PPO run on a jaxenvs task."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest
import requires

import jaxenvs

requires.package("brax", "pip install -e '.[brax]' (.ci/run installs it)")

from brax.envs.base import Env as BraxBaseEnv  # noqa: E402
from brax.envs.wrappers import training as brax_wrappers  # noqa: E402

from jaxenvs.compat.brax import BraxEnv  # noqa: E402

ENV_ID = "CartpoleBalance-v0"
EPISODE = 4


@pytest.fixture(scope="module")
def env() -> BraxEnv:
    return BraxEnv(jaxenvs.make(ENV_ID, episode_length=EPISODE))


@pytest.fixture(scope="module")
def wrapped_rollout(env: BraxEnv) -> tuple[list[object], object]:
    """Brax's own training wrappers (vmap, episode limit, auto-reset) around the adapter,
    stepped past two episode ends with a constant action."""
    wrapped = brax_wrappers.wrap(env, episode_length=EPISODE)
    reset = jax.jit(wrapped.reset)
    step = jax.jit(wrapped.step)
    state = reset(jax.random.split(jax.random.PRNGKey(0), 3))
    first = state
    states = []
    for _ in range(2 * EPISODE + 1):
        state = step(state, jnp.full((3, env.action_size), 0.5))
        states.append(state)
    return states, first


def test_interface(env: BraxEnv) -> None:
    assert isinstance(env, BraxBaseEnv)
    single = jaxenvs.make(ENV_ID)
    assert env.observation_size == single.observation_size
    assert env.action_size == single.action_size
    assert env.backend == "mjx"
    assert env.episode_length == EPISODE
    assert env.unwrapped is env


@pytest.mark.full
def test_reset_and_step_match_jaxenvs(env: BraxEnv) -> None:
    @jax.jit
    def both(key: jax.Array, action: jax.Array) -> tuple:
        state = env.reset(key)
        ours = env.env.reset(key)
        return state, env.step(state, action), ours, env.env.step(ours, action)

    state, nxt, ours, ref = both(jax.random.PRNGKey(1), jnp.array([0.3]))
    np.testing.assert_array_equal(np.asarray(state.obs), np.asarray(ours.obs))
    assert state.pipeline_state is not None
    assert float(state.done) == 0.0 and float(state.reward) == 0.0
    assert set(state.metrics) == set(env.env.metric_keys)
    np.testing.assert_allclose(np.asarray(nxt.obs), np.asarray(ref.obs), atol=1e-6)
    np.testing.assert_allclose(float(nxt.reward), float(ref.reward), atol=1e-6)
    assert float(nxt.reward) != 0.0
    assert nxt.reward.dtype == jnp.float32 and nxt.done.dtype == jnp.float32


@pytest.mark.full
def test_done_is_termination_and_truncation_is_flagged(env: BraxEnv) -> None:
    """Unwrapped: the task's time limit shows in info['truncation'], not in done."""

    @jax.jit
    def run(key: jax.Array) -> tuple:
        def body(s: object, _: None) -> tuple:
            s = env.step(s, jnp.zeros((1,)))
            return s, (s.done, s.info["truncation"], s.info["time_out"])

        return jax.lax.scan(body, env.reset(key), None, length=EPISODE)

    last, (done, trunc, time_out) = run(jax.random.PRNGKey(2))
    np.testing.assert_array_equal(np.asarray(trunc), [0.0] * (EPISODE - 1) + [1.0])
    np.testing.assert_array_equal(np.asarray(time_out), np.asarray(trunc))
    np.testing.assert_array_equal(np.asarray(done), 0.0)  # no failure: done stays 0
    assert float(last.done) == float(last.pipeline_state.terminated)


@pytest.mark.full
def test_brax_wrappers_truncate_and_reset(wrapped_rollout: tuple[list, object]) -> None:
    states, first = wrapped_rollout
    for t, s in enumerate(states, start=1):
        at_limit = t % EPISODE == 0
        done = np.asarray(s.done)
        trunc = np.asarray(s.info["truncation"])
        if at_limit:
            # the episode ended on time, not on a failure: Brax's PPO bootstraps there
            np.testing.assert_array_equal(done, 1.0)
            np.testing.assert_array_equal(trunc, 1.0)
            # AutoResetWrapper put the whole jaxenvs state back to the episode's start
            np.testing.assert_array_equal(np.asarray(s.obs), np.asarray(first.obs))
            np.testing.assert_array_equal(np.asarray(s.pipeline_state.time), 0)
        else:
            np.testing.assert_array_equal(done, 0.0)
            np.testing.assert_array_equal(trunc, 0.0)
            np.testing.assert_array_equal(np.asarray(s.pipeline_state.time), t % EPISODE)


def test_rejects_batched_and_discrete_envs() -> None:
    with pytest.raises(TypeError, match="ONE env"):
        BraxEnv(jaxenvs.make(ENV_ID, num_envs=2))
    with pytest.raises(ValueError, match="continuous"):
        BraxEnv(jaxenvs.make("CartPole-v0"))


@pytest.mark.full
def test_brax_ppo_trains_on_a_jaxenvs_task() -> None:
    """Brax's PPO on CartpoleBalance-v0 runs end to end and its evaluation return rises.

    On MJX: Brax's trainer runs its steps under ``pmap``, where the C engine's host
    callback fails to compile ("mesh should be the same across the entire program")."""
    from brax.training.agents.ppo import train as brax_ppo

    env = BraxEnv(jaxenvs.make(ENV_ID, episode_length=200, physics="mjx"))
    evals: list[float] = []

    def progress(step: int, metrics: dict) -> None:
        evals.append(float(metrics["eval/episode_reward"]))

    brax_ppo.train(
        environment=env,
        num_timesteps=100_000,
        episode_length=env.episode_length,
        num_envs=64,
        batch_size=64,
        num_minibatches=4,
        unroll_length=10,
        num_updates_per_batch=4,
        learning_rate=3e-4,
        discounting=0.97,
        entropy_cost=1e-3,
        num_evals=2,
        num_eval_envs=16,
        seed=0,
        progress_fn=progress,
    )
    assert len(evals) == 2 and all(np.isfinite(evals))
    assert evals[-1] > evals[0] + 20, evals
