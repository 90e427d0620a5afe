"""The functional API's contract: errors, sanitisation, batching, auto-reset."""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import jaxenvs
from jaxenvs.config import ConfigError
from jaxenvs.core import BatchedEnv


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


@pytest.mark.parametrize(
    ("randomize", "physics", "raw_key"),
    [
        (False, "c", False),
        (True, "c", True),  # randomised params, and a raw uint32 key
        pytest.param(False, "mjx", False, marks=pytest.mark.full),  # two MJX compiles
    ],
)
def test_compact_auto_reset_equals_resetting_the_whole_batch(
    monkeypatch, randomize, physics, raw_key
):
    """On a CPU, from 64 envs a device, a step computes fresh starts only for its finished envs
    (compacted into chunks of an eighth of the batch, one loop iteration each): the states
    are those of resetting the whole batch, bit for bit, with one chunk and with several."""
    from jaxenvs.actions import random_actions
    from jaxenvs.core import BatchedEnv, plan
    from jaxenvs.tasks.cartpole import CartPole

    n, steps = 128, 150
    # the plan: compact on a CPU from 64 envs a device, outside a vmap; whole elsewhere
    assert plan(CartPole, "c", n, 1, backend="cpu").reset == "compact"
    assert plan(CartPole, "c", n, 1, backend="cpu").reset_slots(n) == 16
    assert plan(CartPole, "c", 63, 1, backend="cpu").reset == "whole"
    assert plan(CartPole, "c", n, 1, backend="cpu", vmapped=True).reset == "whole"
    assert plan(CartPole, "mjx", n, 1, backend="gpu").reset == "whole"

    def run(mode):
        made = jaxenvs.make("CartPole-v0", num_envs=n, physics=physics, randomize=randomize)
        the_plan = dataclasses.replace(made.plan, devices=1, reset=mode)
        benv = BatchedEnv(made.env, n, randomize=randomize, plan=the_plan)

        def body(s, xs):
            k, i = xs
            # pushing one way for the first steps topples every pole at about the same
            # time (more finished envs than places), random play after that (fewer)
            a = jnp.where(i < 20, 1, random_actions(benv.env, k, (n,)))
            s = benv.step(s, a)
            return s, s.done.sum()

        def rollout(key):
            xs = (jax.random.split(key, steps), jnp.arange(steps))
            return jax.lax.scan(body, benv.reset(key), xs)

        return jax.jit(rollout)(jax.random.PRNGKey(4) if raw_key else jax.random.key(4))

    compact, counts = run("compact")
    whole, _ = run("whole")
    counts = np.asarray(counts)
    assert ((counts > 0) & (counts <= 16)).sum() > 20  # the compact path ran
    assert (counts > 16).any()  # and several chunks (the first wave of falls)
    flat = [
        jax.random.key_data(x) if jax.dtypes.issubdtype(x.dtype, jax.dtypes.prng_key) else x
        for x in jax.tree.leaves((compact, whole))
    ]
    half = len(flat) // 2
    for a, b in zip(flat[:half], flat[half:], strict=True):
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))


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


@pytest.mark.full
def test_params_change_dynamics():
    env = jaxenvs.make("CartpoleBalance-v0")
    s = env.reset(jax.random.key(0))
    params = env.default_params
    heavy = params.replace(model={**params.model, "body_mass": params.model["body_mass"] * 3})
    a = jnp.ones(1)
    v_default = float(env.step(s, a).obs[3])
    v_heavy = float(env.step(s, a, heavy).obs[3])
    assert abs(v_heavy) < abs(v_default)


# ------------------------------------------------ actions and divergence, batched


N = 4


@pytest.fixture(scope="module")
def balance(get_batched):
    """CartpoleBalance, batched over N envs: one jitted reset and step for the session."""
    return get_batched("CartpoleBalance-v0", N)


def test_wrong_action_shape_fails_at_trace_time_naming_the_shape(balance):
    benv, _, _ = balance
    env = benv.env
    s = jax.eval_shape(env.reset, jax.random.key(0))  # tracing only: nothing compiles
    traced = []

    def step(state, action):
        traced.append(action.shape)
        return env.step(state, action)

    with pytest.raises(ValueError, match=r"expected an action of shape \(1,\)"):
        jax.jit(step)(s, jnp.zeros((3,)))
    assert traced == [(3,)]  # raised while tracing, nothing ran on device
    with pytest.raises(TypeError, match="floating-point.*Box"):
        jax.jit(env.step)(s, jnp.zeros((1,), jnp.int32))
    bs = jax.eval_shape(benv.reset, jax.random.key(0))
    with pytest.raises(ValueError, match=r"expected actions of shape \(4, 1\)"):
        jax.jit(benv.step)(bs, jnp.zeros((N,)))
    discrete = jaxenvs.make("CartPole-v0")
    ds = jax.eval_shape(discrete.reset, jax.random.key(0))
    with pytest.raises(TypeError, match="integer action"):
        jax.jit(discrete.step)(ds, jnp.float32(1.0))


def test_out_of_range_actions_are_clipped(balance):
    benv, reset, step = balance
    s = reset(jax.random.key(1))
    over = step(s, jnp.array([[5.0], [-5.0], [1.5], [-1e30]]))
    edge = step(s, jnp.array([[1.0], [-1.0], [1.0], [-1.0]]))
    np.testing.assert_array_equal(np.asarray(over.data.qpos), np.asarray(edge.data.qpos))
    np.testing.assert_array_equal(np.asarray(over.info["nan_actions"]), np.zeros(N))


def test_nan_and_inf_actions_are_zeroed_counted_and_isolated(balance):
    """Each non-finite action acts as 0 and is counted for its own env only."""
    benv, reset, step = balance
    s = reset(jax.random.key(2))
    bad = step(s, jnp.array([[jnp.nan], [jnp.inf], [0.3], [-jnp.inf]]))
    good = step(s, jnp.array([[0.0], [0.0], [0.3], [0.0]]))
    assert np.asarray(bad.info["nan_actions"]).tolist() == [1, 1, 0, 1]
    assert np.asarray(good.info["nan_actions"]).tolist() == [0, 0, 0, 0]
    for a, b in zip(jax.tree.leaves(bad.data), jax.tree.leaves(good.data), strict=True):
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))
    np.testing.assert_array_equal(np.asarray(bad.obs), np.asarray(good.obs))


def test_extreme_actions_keep_the_state_finite(balance):
    """60 steps of +-1e9 / +-inf / NaN: finite obs, rewards and physics throughout."""
    benv, reset, step = balance
    s = reset(jax.random.key(3))
    values = jnp.array([1e9, -1e9, jnp.inf, jnp.nan], jnp.float32)
    for t in range(60):
        s = step(s, jnp.roll(values, t)[:, None])
        for x in (s.obs, s.reward, s.data.qpos, s.data.qvel, s.info["final_obs"]):
            assert np.all(np.isfinite(np.asarray(x))), t
    assert int(np.asarray(s.info["nan_actions"]).sum()) == 2  # NaN and inf, each step


def test_diverged_env_is_flagged_reset_and_the_others_untouched(balance):
    """A velocity past the documented bound (finite, not NaN) also terminates."""
    benv, reset, step = balance
    s = reset(jax.random.key(4))
    bound = benv.config.divergence_bound
    qvel = s.data.qvel.at[2, 0].set(10 * bound)
    poisoned = s.replace(data=s.data.replace(qvel=qvel))
    a = jnp.full((N, 1), 0.5, jnp.float32)
    clean, bad = step(s, a), step(poisoned, a)
    assert np.asarray(bad.info["diverged"]).tolist() == [False, False, True, False]
    assert bool(bad.terminated[2]) and int(bad.time[2]) == 0 and float(bad.reward[2]) == 0.0
    assert np.all(np.abs(np.asarray(bad.data.qvel[2])) < bound)  # reset to a fresh start
    assert np.all(np.abs(np.asarray(bad.info["final_obs"][2])) <= bound)
    for i in (0, 1, 3):
        for x, y in zip(jax.tree.leaves(clean), jax.tree.leaves(bad), strict=True):
            if jax.dtypes.issubdtype(x.dtype, jax.dtypes.prng_key):
                x, y = jax.random.key_data(x), jax.random.key_data(y)
            np.testing.assert_array_equal(np.asarray(x[i]), np.asarray(y[i]))


def test_batched_reset_and_step_compile_once(balance):
    """Feeding step's output back in, NaN actions and auto-resets never retrace."""
    benv, reset, step = balance
    s = reset(jax.random.key(5))
    s = reset(jax.random.key(6))
    for t in range(30):
        a = jnp.full((N, 1), jnp.nan if t % 3 == 0 else 1.0, jnp.float32)
        s = step(s, a)
    assert bool(np.asarray(s.info["final_length"]).max() > 0)
    assert reset._cache_size() == 1
    assert step._cache_size() == 1


# ------------------------------------------------- keys and states of the wrong kind


@pytest.fixture(scope="module")
def envs():
    env = jaxenvs.make("CartPole-v0", physics="c")
    batched = BatchedEnv(env, 3)
    return env, batched, env.reset(jax.random.key(0)), batched.reset(jax.random.key(0))


@pytest.mark.parametrize(
    "call, error, words",
    [
        (lambda e, b, s, bs: e.reset(0), TypeError, "CartPole.reset: expected a PRNG key"),
        (
            lambda e, b, s, bs: e.reset(jax.random.split(jax.random.key(0), 3)),
            ValueError,
            "CartPole.reset: expected one PRNG key",
        ),
        (lambda e, b, s, bs: e.step(bs, 0), ValueError, "CartPole.step: expected one env's state"),
        (lambda e, b, s, bs: e.step({}, 0), TypeError, "CartPole.step: expected a State"),
        (lambda e, b, s, bs: b.reset(0), TypeError, "batched CartPole.reset: expected a PRNG key"),
        (
            lambda e, b, s, bs: b.step(s, np.zeros(3, np.int32)),
            ValueError,
            "batched CartPole.step: expected a state of 3 envs, got one env's state",
        ),
    ],
)
def test_the_wrong_key_or_state_gets_the_envs_own_message(envs, call, error, words):
    with pytest.raises(error) as err:
        call(*envs)
    assert str(err.value).startswith(words) and "\n" not in str(err.value)


def test_the_right_keys_and_states_still_work(envs):
    env, batched, state, batch_state = envs
    assert env.step(state, 1).time == 1
    assert batched.step(batch_state, np.ones(3, np.int32)).time.shape == (3,)
    assert env.reset(jax.random.PRNGKey(0)).obs.shape == (env.observation_size,)
    stepped = jax.vmap(env.step)(batch_state, np.ones(3, np.int32))
    assert stepped.time.shape == (3,)
