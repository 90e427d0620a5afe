"""The functional API's contract: errors, sanitisation, batching, auto-reset."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import jaxenvs
from jaxenvs.config import ConfigError


def test_list_envs_has_the_cartpoles():
    ids = jaxenvs.list_envs()
    for env_id in ["CartPole-v0", "CartpoleStayUp-v0", "CartpoleBalance-v0", "CartpoleSwingup-v0"]:
        assert env_id in ids


def test_unknown_id_names_valid_ones():
    with pytest.raises(ValueError, match="unknown env id 'Nope-v0'.*CartPole-v0"):
        jaxenvs.make("Nope-v0")


def test_unknown_override_lists_valid_keys():
    with pytest.raises(ConfigError, match="episode_lenght.*valid keys:.*episode_length"):
        jaxenvs.make("CartpoleBalance-v0", episode_lenght=500)


def test_wrong_type_and_impossible_value():
    with pytest.raises(ConfigError, match="episode_length.*integer"):
        jaxenvs.make("CartpoleBalance-v0", episode_length="long")
    with pytest.raises(ConfigError, match="episode_length.*positive"):
        jaxenvs.make("CartpoleBalance-v0", episode_length=-5)


def test_override_applies():
    env = jaxenvs.make("CartpoleBalance-v0", episode_length=500)
    assert env.episode_length == 500
    assert env.observation_size == 5 and env.action_size == 1


def test_spaces_and_sizes():
    env = jaxenvs.make("CartPole-v0")
    assert env.action_space.n == 2 and env.observation_space.shape == (4,)


def test_wrong_action_shape_and_dtype():
    env = jaxenvs.make("CartpoleBalance-v0")
    s = env.reset(jax.random.key(0))
    with pytest.raises(ValueError, match=r"expected an action of shape \(1,\)"):
        env.step(s, jnp.zeros(2))
    with pytest.raises(TypeError, match="floating-point"):
        env.step(s, jnp.zeros(1, jnp.int32))
    denv = jaxenvs.make("CartPole-v0")
    ds = denv.reset(jax.random.key(0))
    with pytest.raises(TypeError, match="integer action"):
        denv.step(ds, jnp.float32(1.0))


def test_nan_action_never_reaches_physics():
    env = jaxenvs.make("CartpoleBalance-v0")
    step = jax.jit(env.step)
    s = env.reset(jax.random.key(0))
    bad = step(s, jnp.array([jnp.nan]))
    zero = step(s, jnp.array([0.0]))
    assert int(bad.info["nan_actions"]) == 1 and int(zero.info["nan_actions"]) == 0
    np.testing.assert_array_equal(np.asarray(bad.data.qpos), np.asarray(zero.data.qpos))
    big = step(s, jnp.array([1e9]))
    one = step(s, jnp.array([1.0]))
    np.testing.assert_array_equal(np.asarray(big.data.qpos), np.asarray(one.data.qpos))


def test_discrete_out_of_range_is_clipped():
    env = jaxenvs.make("CartPole-v0")
    s = env.reset(jax.random.key(0))
    np.testing.assert_array_equal(
        np.asarray(env.step(s, jnp.int32(7)).obs), np.asarray(env.step(s, jnp.int32(1)).obs)
    )


@pytest.mark.parametrize("physics", ["auto", pytest.param("mjx", marks=pytest.mark.full)])
def test_diverged_env_terminates_and_is_isolated(get_batched, physics):
    """One env with a non-finite state is terminated and reset; the others are
    bit-for-bit what they would have been (on either engine: MuJoCo C would reset the
    state itself, the C engine hands it back as NaN)."""
    _, reset, step = get_batched("CartpoleBalance-v0", 4, physics=physics)
    s = reset(jax.random.key(0))
    qpos = s.data.qpos.at[1, 1].set(jnp.nan)
    poisoned = s.replace(data=s.data.replace(qpos=qpos))
    a = jnp.zeros((4, 1))
    clean_next = step(s, a)
    bad_next = step(poisoned, a)
    assert np.asarray(bad_next.info["diverged"]).tolist() == [False, True, False, False]
    assert bool(bad_next.terminated[1])
    assert np.all(np.isfinite(np.asarray(bad_next.obs)))
    assert np.all(np.isfinite(np.asarray(bad_next.data.qpos)))
    assert int(bad_next.time[1]) == 0
    for i in (0, 2, 3):
        np.testing.assert_array_equal(np.asarray(bad_next.obs[i]), np.asarray(clean_next.obs[i]))


def test_batched_shapes_and_fresh_autoreset(get_checker):
    # the battery's 8-env, 300-step random rollout of CartPole-v0 (compiled once)
    checker = get_checker("CartPole-v0")
    benv = checker.benv
    s, traj = checker.rollout()
    assert s.obs.shape == (8, 4)
    with pytest.raises(ValueError, match=r"expected actions of shape \(8,\)"):
        benv.step(s, jnp.zeros((4,), jnp.int32))
    obs, final = np.asarray(traj.obs), np.asarray(traj.info["final_obs"])
    done, time = np.asarray(traj.done), np.asarray(traj.time)
    flen, fret = np.asarray(traj.info["final_length"]), np.asarray(traj.info["final_return"])
    assert done.sum() > 16  # random play ends CartPole episodes within ~20-40 steps
    starts = obs[done]
    assert np.all(np.abs(starts) <= 0.05)  # a fresh start from the init distribution
    assert len(np.unique(starts[:, 0])) == len(starts)  # fresh, not cached
    assert np.all(time[done] == 0)
    assert np.all(np.abs(final[done][:, 2]) > 0.2) or np.all(np.abs(final[done][:, 0]) > 0)
    # final return of CartPole = final length (+1 per step)
    np.testing.assert_array_equal(fret[done], flen[done])
    assert np.all(flen[done] >= 1)


def test_scan_unroll_hints_are_set():
    benv = jaxenvs.make("CartPole-v0", num_envs=8, physics="mjx")
    assert benv.scan_unroll > 1  # the cartpole's measured choice (benchmarks/NOTES.md)
    # a C step is a host call that cannot fuse across steps: no unrolling there
    assert jaxenvs.make("CartPole-v0", num_envs=8, physics="c").scan_unroll == 1
    assert all(isinstance(jaxenvs.make(i).scan_unroll, int) for i in jaxenvs.list_envs())


@pytest.mark.full  # two MJX compiles of a 30-step scan, one of them unrolled
def test_scan_unroll_hint_does_not_change_results():
    """The unroll hint is a compile choice only: same keys, same trajectory. On MJX,
    whose compile the hint is measured for."""
    benv = jaxenvs.make("CartPole-v0", num_envs=8, physics="mjx")
    assert benv.scan_unroll > 1

    def rollout(unroll):
        def run(key):
            def body(s, k):
                s = benv.step(s, jax.random.randint(k, (8,), 0, 2))
                return s, (s.obs, s.done)

            keys = jax.random.split(key, 30)
            return jax.lax.scan(body, benv.reset(key), keys, unroll=unroll)[1]

        return jax.jit(run)(jax.random.key(3))

    (obs1, done1), (obs5, done5) = rollout(1), rollout(benv.scan_unroll)
    np.testing.assert_array_equal(np.asarray(done1), np.asarray(done5))
    np.testing.assert_allclose(np.asarray(obs1), np.asarray(obs5), rtol=1e-5, atol=1e-5)
    assert np.asarray(done1).any()


def test_params_change_dynamics():
    env = jaxenvs.make("CartpoleBalance-v0")
    s = env.reset(jax.random.key(0))
    params = env.default_params
    heavy = params.replace(model={**params.model, "body_mass": params.model["body_mass"] * 3})
    a = jnp.ones(1)
    v_default = float(env.step(s, a).obs[3])
    v_heavy = float(env.step(s, a, heavy).obs[3])
    assert abs(v_heavy) < abs(v_default)
