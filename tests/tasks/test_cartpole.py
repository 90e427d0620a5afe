"""Task-level checks of the cartpole family that could fail."""

from __future__ import annotations

import gymnasium as gym
import jax
import jax.numpy as jnp
import numpy as np
import pytest

import jaxenvs


@pytest.fixture(scope="module")
def classic():
    env = jaxenvs.make("CartPole-v0")
    return env, jax.jit(env.reset), jax.jit(env.step)


def _gym_cartpole(integrator: str):
    g = gym.make("CartPole-v1").unwrapped
    g.kinematics_integrator = integrator
    g.reset(seed=0)
    return g


@pytest.mark.full
def test_classic_tracks_gymnasium_semi_implicit(classic):
    """MJX's Euler is semi-implicit; Gymnasium's CartPole in that mode must agree to
    float32 precision (same masses, pole inertia, force and 0.02 s step)."""
    env, reset, step = classic
    s = reset(jax.random.key(0))
    g = _gym_cartpole("semi-implicit euler")
    g.state = np.asarray(s.obs, np.float64)
    rng = np.random.default_rng(0)
    for _ in range(15):
        a = int(rng.integers(2))
        s = step(s, jnp.int32(a))
        obs, _, term, _, _ = g.step(a)
        np.testing.assert_allclose(np.asarray(s.obs), obs, atol=1e-4)
        assert bool(s.terminated) == term


def test_classic_close_to_gymnasium_default(classic):
    """Against CartPole-v1's default explicit Euler the difference is the integrator's
    O(dt) discrepancy: measured <= 0.07 per variable over 15 steps; we allow 0.1."""
    env, reset, step = classic
    s = reset(jax.random.key(1))
    g = _gym_cartpole("euler")
    g.state = np.asarray(s.obs, np.float64)
    for t in range(15):
        a = t % 2
        s = step(s, jnp.int32(a))
        obs, *_ = g.step(a)
        assert np.abs(np.asarray(s.obs) - obs).max() < 0.1


def test_classic_truncates_at_500():
    env = jaxenvs.make("CartPole-v0", theta_threshold=100.0, x_threshold=1e3)
    s = env.reset(jax.random.key(0))

    def body(s, _):
        s = env.step(s, jnp.int32(0))
        return s, (s.terminated, s.truncated, s.reward)

    _, (term, trunc, rew) = jax.jit(lambda s: jax.lax.scan(body, s, None, length=500))(s)
    assert not np.asarray(term).any()
    assert np.asarray(trunc)[-1] and not np.asarray(trunc)[:-1].any()
    assert np.asarray(rew).sum() == 500


def test_classic_terminates_past_12_degrees(classic):
    env, reset, step = classic
    s = reset(jax.random.key(0))
    data = s.data.replace(qpos=jnp.array([0.0, 0.20]), qvel=jnp.array([0.0, 1.0]))
    s = step(s.replace(data=data), jnp.int32(1))
    assert bool(s.terminated) and not bool(s.truncated)
    assert float(s.reward) == 1.0


@pytest.mark.full
def test_classic_start_distribution(classic):
    env, reset, _ = classic
    obs = np.stack([np.asarray(reset(k).obs) for k in jax.random.split(jax.random.key(2), 64)])
    assert np.all(np.abs(obs) <= 0.05)
    assert obs.std(axis=0).min() > 0.02  # uniform on +-0.05 has std 0.029


@pytest.mark.full
def test_swingup_starts_hanging():
    env = jaxenvs.make("CartpoleSwingup-v0")
    obs = np.asarray(jax.vmap(env.reset)(jax.random.split(jax.random.key(0), 32)).obs)
    assert np.all(obs[:, 1] < -0.99)  # cos(angle) ~ -1: pole hanging down
    balance = jaxenvs.make("CartpoleBalance-v0")
    obs = np.asarray(balance.reset(jax.random.key(0)).obs)
    assert obs[1] > 0.99


@pytest.mark.full
def test_balance_reward_is_dense_and_bounded():
    env = jaxenvs.make("CartpoleBalance-v0")
    s = env.reset(jax.random.key(0))
    s = jax.jit(env.step)(s, jnp.zeros(1))
    assert 0.9 < float(s.reward) <= 1.0
    s = jax.jit(env.step)(s, jnp.ones(1))
    assert float(s.reward) < 0.85  # full force costs the small-control factor


@pytest.mark.full
def test_stayup_commands_move_the_cart():
    env = jaxenvs.make("CartpoleStayUp-v0", init_noise=0.0, max_pole_angle=3.2, min_pole_angle=-3.2)
    step = jax.jit(env.step)
    s = env.reset(jax.random.key(0))
    for _ in range(10):
        s = step(s, jnp.int32(3))  # big right: +10 * pos_step each
    np.testing.assert_allclose(float(s.info["command"]), 10 * 10 * 0.016, rtol=1e-5)
    assert float(s.obs[1]) > 0.5 * 1.6  # velocity servo tracks the command
    x_right = float(s.obs[0])
    s = env.reset(jax.random.key(0))
    for _ in range(10):
        s = step(s, jnp.int32(0))  # small left
    assert float(s.obs[1]) < 0 and float(s.obs[0]) < 0 < x_right


def test_stayup_two_actions_and_bounds():
    env = jaxenvs.make("CartpoleStayUp-v0", n_actions=2)
    assert env.action_size == 2
    s = env.reset(jax.random.key(0))
    data = s.data.replace(qpos=jnp.array([2.6, 0.0]))
    s = env.step(s.replace(data=data), jnp.int32(1))
    assert bool(s.terminated)


def test_stayup_running_step_sets_substeps():
    env = jaxenvs.make("CartpoleStayUp-v0", running_step=0.08)
    assert env.sim.substeps == 8
    assert abs(env.control_dt - 0.08) < 1e-12
