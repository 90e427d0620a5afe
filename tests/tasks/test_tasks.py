"""The task hooks' key contract: ``reset`` and ``step`` split the key once into named
subkeys, each hook gets its own, and a task with observation noise stays deterministic per
key (and passes the battery). Also: termination is its own hook, and a reward hook that
returns more than ``(reward, metrics)`` is refused with a message saying so."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from engines import TASK_LOGIC

import jaxenvs
from jaxenvs.core import NoExtras
from jaxenvs.tasks.cartpole import BalanceConfig, CartpoleBalance, StayUpExtras
from jaxenvs.tasks.hexapod import OneLegExtras
from jaxenvs.testing import TaskChecker, TaskCheckError, check_task

NOISE = 0.05


class NoisyBalance(CartpoleBalance):
    """CartpoleBalance with Gaussian sensor noise drawn from the observation key."""

    def _observe(self, key, data, extras, params):  # type: ignore[no-untyped-def]
        obs = super()._observe(key, data, extras, params)
        return obs + NOISE * jax.random.normal(key, obs.shape)


class KeySpy(CartpoleBalance):
    """Records the keys its hooks receive (run eagerly: the keys are concrete)."""

    seen: list[tuple[str, np.ndarray]]

    def _act(self, key, data, extras, action, params):  # type: ignore[no-untyped-def]
        self.seen.append(("act", np.asarray(jax.random.key_data(key))))
        return super()._act(key, data, extras, action, params)

    def _observe(self, key, data, extras, params):  # type: ignore[no-untyped-def]
        self.seen.append(("obs", np.asarray(jax.random.key_data(key))))
        return super()._observe(key, data, extras, params)


class StaleKeyStep(NoisyBalance):
    """Bug: the step ignores the state's key and always draws from the same one."""

    def step(self, state, action, params=None):  # type: ignore[no-untyped-def]
        return super().step(state.replace(key=jax.random.key(0)), action, params)


def _config() -> BalanceConfig:
    return BalanceConfig(physics=TASK_LOGIC)


def _data(key: jax.Array) -> np.ndarray:
    return np.asarray(jax.random.key_data(key))


@pytest.fixture(scope="module")
def noisy() -> tuple[NoisyBalance, CartpoleBalance, object, object]:
    env, plain = NoisyBalance(_config()), CartpoleBalance(_config())
    return env, plain, jax.jit(env.reset), jax.jit(env.step)


@pytest.mark.full
def test_noisy_task_passes_the_battery() -> None:
    check_task(NoisyBalance(_config()), rollout_steps=100)


@pytest.mark.full
def test_noise_is_deterministic_per_key_and_differs_across_keys(noisy) -> None:
    env, plain, reset, step = noisy
    s = reset(jax.random.key(1))
    act = jnp.full((1,), 0.3)
    a, a2 = step(s, act), step(s, act)
    b = step(s.replace(key=jax.random.key(2)), act)
    np.testing.assert_array_equal(a.obs, a2.obs)
    np.testing.assert_array_equal(a.data.qpos, b.data.qpos)  # the noise is the obs's only
    assert not np.allclose(a.obs, b.obs)
    clean = plain.step(s, act)
    assert 0 < np.abs(np.asarray(a.obs - clean.obs)).max() < 10 * NOISE


def test_reset_noise_leaves_the_initial_state_alone(noisy) -> None:
    """The observation key is a third subkey: the init key, and so the initial physics
    state and the state's next key, are the same as a noiseless task's."""
    env, plain, reset, _ = noisy
    s, p = reset(jax.random.key(3)), plain.reset(jax.random.key(3))
    np.testing.assert_array_equal(s.data.qpos, p.data.qpos)
    np.testing.assert_array_equal(_data(s.key), _data(p.key))
    assert not np.allclose(s.obs, p.obs)


def test_step_splits_the_key_once_into_distinct_named_subkeys() -> None:
    env = KeySpy(_config())
    env.seen = []
    key = jax.random.key(4)
    s = env.reset(key)
    next_key, init_key, obs_key = jax.random.split(key, 3)
    [(name, reset_obs_key)] = env.seen
    assert name == "obs"
    np.testing.assert_array_equal(reset_obs_key, _data(obs_key))
    np.testing.assert_array_equal(_data(s.key), _data(next_key))
    env.seen = []
    s2 = env.step(s, jnp.zeros(1))
    expect = jax.random.split(s.key, 3)
    (act_name, act_key), (obs_name, obs_key2) = env.seen
    assert (act_name, obs_name) == ("act", "obs")
    np.testing.assert_array_equal(act_key, _data(expect[1]))
    np.testing.assert_array_equal(obs_key2, _data(expect[2]))
    np.testing.assert_array_equal(_data(s2.key), _data(expect[0]))
    used = [_data(s.key), act_key, obs_key2, _data(s2.key), _data(init_key), _data(obs_key)]
    assert len({k.tobytes() for k in used}) == len(used)  # no key used twice


@pytest.mark.full
def test_battery_names_a_step_that_ignores_the_state_key() -> None:
    checker = TaskChecker(StaleKeyStep(_config()))
    with pytest.raises(TaskCheckError, match=r"^\[keys\] step did not advance state.key"):
        checker.check_keys()


def test_termination_is_its_own_hook() -> None:
    env = CartpoleBalance(_config())
    params = env.default_params
    s = env.reset(jax.random.key(5))
    beyond = s.data.replace(qpos=s.data.qpos.at[0].set(2.0))
    assert bool(env._terminated(beyond, NoExtras(), params))
    assert not bool(env._terminated(s.data, NoExtras(), params))
    reward, metrics = env._reward(s.data, s.data, jnp.zeros(1), NoExtras(), params)
    assert reward.shape == () and metrics == {}


def test_a_reward_that_still_returns_termination_is_refused() -> None:
    class OldReward(CartpoleBalance):
        def _reward(self, prev, data, action, extras, params):  # type: ignore[no-untyped-def]
            reward, metrics = super()._reward(prev, data, action, extras, params)
            return reward, jnp.zeros((), bool), metrics

    env = OldReward(_config())
    with pytest.raises(TypeError, match=r"_reward must return \(reward, metrics\)"):
        env.step(env.reset(jax.random.key(0)), jnp.zeros(1))


def test_extras_are_typed_per_task() -> None:
    key = jax.random.key(0)
    stay = jaxenvs.make("CartpoleStayUp-v0", physics=TASK_LOGIC).reset(key)
    assert isinstance(stay.extras, StayUpExtras) and stay.extras.command.dtype == jnp.float32
    leg = jaxenvs.make("HexapodOneLeg-v0", physics=TASK_LOGIC).reset(key)
    assert isinstance(leg.extras, OneLegExtras) and leg.extras.target_q.shape == (3,)
    assert isinstance(jaxenvs.make("Reacher-v0", physics=TASK_LOGIC).reset(key).extras, NoExtras)
