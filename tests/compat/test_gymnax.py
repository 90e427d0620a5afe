"""The gymnax adapter (jaxenvs.compat.gymnax): gymnax's Environment interface, the auto-reset
inside step, params as gymnax params (time limit and domain randomisation), and gymnax-API
training (rejax's PPO) on two tasks."""

from __future__ import annotations

import copy
import re
import runpy
import time
from pathlib import Path

import counting_task
import jax
import jax.numpy as jnp
import numpy as np
import pytest
import requires

import jaxenvs

requires.package("gymnax", "pip install -e '.[gymnax]' (the test extra includes it)")

from gymnax.environments import environment, spaces  # noqa: E402

from jaxenvs.compat import gymnax as jgx  # noqa: E402

N = 4


@pytest.fixture(scope="module")
def cartpole():
    return jgx.make("CartPole-v0")


@pytest.fixture(scope="module")
def vstep(cartpole):
    """CartPole's step vmapped as gymnax-API code vmaps it, params batched too."""
    env, _ = cartpole
    return jax.jit(jax.vmap(env.step, in_axes=(0, 0, 0, 0)))


def _keys(seed: int, n: int = N) -> jax.Array:
    return jax.random.split(jax.random.PRNGKey(seed), n)


def _batch(params, n: int = N):
    return jax.tree.map(lambda x: jnp.broadcast_to(jnp.asarray(x), (n, *jnp.shape(x))), params)


def test_every_id_is_a_gymnax_environment():
    for env_id in jaxenvs.list_envs():
        env, params = jgx.make(env_id)
        task = env.jax_env
        assert isinstance(env, environment.Environment) and env.name == env_id
        assert params.max_steps_in_episode == task.episode_length
        obs_space = env.observation_space(params)
        assert isinstance(obs_space, spaces.Box)
        assert obs_space.shape == (task.observation_size,) and obs_space.dtype == jnp.float32
        act = env.action_space(params)
        if task.discrete:
            assert isinstance(act, spaces.Discrete) and act.n == task.action_size
        else:
            assert isinstance(act, spaces.Box) and act.shape == (task.action_size,)
            assert (act.low, act.high) == (-1.0, 1.0)
        assert env.num_actions == task.action_size


def test_reset_and_step_follow_gymnax_and_the_functional_api(cartpole):
    env, params = cartpole
    obs, state = env.reset(jax.random.PRNGKey(3), params)
    typed_obs, _ = env.reset(jax.random.key(3), params)  # a typed key: the same start
    np.testing.assert_array_equal(obs, typed_obs)
    assert obs.shape == (4,) and obs.dtype == jnp.float32 and int(state.time) == 0
    key = jax.random.PRNGKey(7)
    obs, nxt, reward, done, info = env.step(key, state, jnp.int32(1), params)
    assert reward.dtype == jnp.float32 and float(reward) == 1.0
    assert done.dtype == jnp.bool_ and not bool(done) and int(nxt.time) == 1
    metrics = set(env.jax_env.metric_keys)
    base = {"discount", "terminated", "truncated", "final_observation", "nan_actions", "diverged"}
    assert set(info) == base | metrics
    assert float(info["discount"]) == 1.0
    # the step's random draws come from the key given, as the env's own step from state.key
    step_key = jax.random.split(jax.random.wrap_key_data(key))[0]
    ref = jax.jit(env.jax_env.step)(state.replace(key=step_key), jnp.int32(1))
    np.testing.assert_array_equal(obs, ref.obs)
    np.testing.assert_array_equal(info["final_observation"], ref.obs)


def test_auto_reset_inside_step_with_a_traced_time_limit(cartpole, vstep):
    """Each env's time limit is its own params' max_steps_in_episode: where a step ends the
    episode it returns a fresh start drawn from its key, and keeps the last obs in info."""
    env, params = cartpole
    limits = jnp.array([2, 3, 2, 3])
    batch = _batch(params).replace(max_steps_in_episode=limits)
    obs, state = jax.vmap(env.reset, in_axes=(0, 0))(_keys(0), batch)
    fresh = jax.jit(jax.vmap(env.reset, in_axes=(0, 0)))
    ones = jnp.ones(N, jnp.int32)
    for t in range(1, 5):
        keys = _keys(t)
        obs, state, reward, done, info = vstep(keys, state, ones, batch)
        ended = np.asarray(t % limits == 0)
        np.testing.assert_array_equal(done, ended)
        np.testing.assert_array_equal(info["truncated"], ended)
        assert not np.asarray(info["terminated"]).any() and (np.asarray(reward) == 1.0).all()
        np.testing.assert_array_equal(state.time, np.where(ended, 0, t % limits))
        split = jax.vmap(lambda k: jax.random.split(jax.random.wrap_key_data(k))[1])(keys)
        start, _ = fresh(split, batch)
        np.testing.assert_array_equal(np.asarray(obs)[ended], np.asarray(start)[ended])
        last = np.asarray(info["final_observation"])
        assert not np.isin(last[ended], np.asarray(obs)[ended]).any()
        np.testing.assert_array_equal(last[~ended], np.asarray(obs)[~ended])
    assert ended.any() and not ended.all()


def test_termination_resets_unbatched_under_scan(cartpole):
    """A constant push topples the pole: the terminal step has discount 0 and the next
    state starts a new episode (the unbatched step under lax.scan)."""
    env, params = cartpole

    def run(key):
        _, state = env.reset(key, params)

        def body(state, k):
            _, state, _, done, info = env.step(k, state, jnp.int32(1), params)
            return state, (done, info["terminated"], info["discount"], state.time)

        return jax.lax.scan(body, state, jax.random.split(key, 60))[1]

    done, terminated, discount, time = (np.asarray(x) for x in jax.jit(run)(jax.random.key(1)))
    first = int(np.argmax(terminated))
    assert terminated.any() and done[first] and discount[first] == 0.0
    assert time[first] == 0 and time[first - 1] == first
    assert (discount[~terminated] == 1.0).all()


def test_the_task_carry_survives_the_auto_reset():
    """A task's per-env carry (CountingCartPole: finished episodes, which also shift the
    next start k mm right) is updated from each finished episode before the fresh start."""
    env = jgx.GymnaxEnv(counting_task.make(episode_length=3))
    params = env.default_params
    plain = jaxenvs.make("CartPole-v0", physics=env.jax_env.physics)

    def run(key):
        _, state = env.reset(key, params)

        def body(state, k):
            obs, state, _, done, _ = env.step(k, state, jnp.int32(1), params)
            unshifted = plain.reset(jax.random.split(jax.random.wrap_key_data(k))[1]).obs
            return state, (done, state.carry, obs[0] - unshifted[0])

        return jax.lax.scan(body, state, jax.random.split(key, 10))[1]

    keys = jax.random.split(jax.random.PRNGKey(2), N)
    done, carry, shift = (np.asarray(x) for x in jax.jit(jax.vmap(run))(keys))
    np.testing.assert_array_equal(carry, np.cumsum(done, axis=1))
    assert (carry[:, -1] == 3).all()
    np.testing.assert_allclose(shift[done], 1e-3 * carry[done], atol=1e-6)


def test_params_randomise_the_dynamics():
    """sample_params draws the task's params (Reacher: link masses, target radius); a
    vmapped step with a batch of them runs each env under its own."""
    env, params = jgx.make("Reacher-v0")
    drawn = jax.vmap(env.sample_params)(_keys(5, 3))
    masses = np.asarray(drawn.task.model["body_mass"])
    assert len({tuple(m) for m in masses}) == 3
    np.testing.assert_array_equal(drawn.max_steps_in_episode, params.max_steps_in_episode)
    same = jnp.broadcast_to(jax.random.PRNGKey(0), (3, 2))
    _, state = jax.vmap(env.reset, in_axes=(0, 0))(same, drawn)
    action = jnp.ones((3, 2), jnp.float32)
    obs, *_ = jax.jit(jax.vmap(env.step, in_axes=(0, 0, 0, 0)))(same, state, action, drawn)
    assert len({tuple(np.round(o, 6)) for o in np.asarray(obs)}) == 3


def test_bad_input_and_copies(cartpole):
    env, _ = cartpole
    with pytest.raises(Exception, match="Nope-v0"):
        jgx.make("Nope-v0")
    with pytest.raises(TypeError, match="builds ONE env.*num_envs"):
        jgx.make("CartPole-v0", num_envs=4)
    with pytest.raises(TypeError, match="ONE jaxenvs Env"):
        jgx.GymnaxEnv(jaxenvs.make("CartPole-v0", num_envs=2))
    assert jgx.make("CartPole-v0", episode_length=7)[1].max_steps_in_episode == 7
    assert copy.deepcopy(env) is env  # immutable; training code deep-copies its config


# ---------------------------------------------------------------- gymnax-API training
def _greedy_eval(env, params):
    """rejax's eval callback with the greedy action (the mode, or the Gaussian's mean)."""
    from rejax.evaluate import evaluate

    def callback(algo, ts, rng):
        def act(obs, rng):
            if algo.normalize_observations:
                obs = algo.normalize_obs(ts.obs_rms_state, obs)
            dist = algo.actor.apply(ts.actor_ts.params, obs[None], method="_action_dist")
            action = jnp.squeeze(dist.mode() if algo.discrete else dist.mean(), 0)
            return action if algo.discrete else jnp.clip(action, -1.0, 1.0)

        return evaluate(act, rng, env, params, 32, params.max_steps_in_episode)

    return callback


#: rejax PPO settings per id; CartPole-v0 as the shipped jaxenvs config, Reacher-v0 too
#: (one 50-step episode per env per rollout)
PPO_RUNS = {
    "CartPole-v0": (
        dict(num_envs=16, num_steps=128, learning_rate=1e-3, total_timesteps=131_072),
        475.0,
    ),
    "Reacher-v0": (
        dict(
            num_envs=64,
            num_steps=50,
            learning_rate=3e-4,
            total_timesteps=1_280_000,
            gamma=0.95,
            normalize_observations=True,
        ),
        -3.75,  # the shipped PPO config's bar; a random policy scores -13.0, zeros -11.8
    ),
}


@pytest.mark.full
@pytest.mark.parametrize("env_id", list(PPO_RUNS))
def test_rejax_ppo_trains_through_the_adapter(env_id):
    """rejax's own PPO trains and evaluates greedily in one jitted program."""
    rejax = requires.package("rejax", "pip install -e '.[test]' (it includes rejax)")
    env, params = jgx.make(env_id)
    settings, bar = PPO_RUNS[env_id]
    config = {
        "num_epochs": 4,
        "num_minibatches": 4,
        "max_grad_norm": 0.5,
        "gamma": 0.99,
        "gae_lambda": 0.95,
        "clip_eps": 0.2,
        "ent_coef": 0.0,
        "normalize_rewards": True,
        "skip_initial_evaluation": True,
        "agent_kwargs": {"activation": "tanh", "hidden_layer_sizes": (64, 64)},
        **settings,
    }
    config["eval_freq"] = config["total_timesteps"]  # one greedy evaluation, at the end
    algo = rejax.PPO.create(env=env, env_params=params, **config)
    algo = algo.replace(eval_callback=_greedy_eval(env, params))
    start = time.perf_counter()
    _, (lengths, returns) = jax.jit(algo.train)(jax.random.PRNGKey(0))
    mean = float(np.asarray(returns)[-1].mean())
    print(f"{env_id}: greedy mean return {mean:.2f}, {time.perf_counter() - start:.1f} s")
    assert mean >= bar, f"{env_id}: greedy mean return {mean:.2f} < {bar}"


@pytest.mark.full
def test_docs_purejaxrl_example_trains(capsys, tmp_path):
    """docs/gymnax.md's PureJaxRL-style PPO runs as written and reaches a greedy 475+."""
    doc = (Path(__file__).parents[2] / "docs" / "gymnax.md").read_text()
    section = doc.split("## A PureJaxRL-style PPO", 1)[1]
    script = tmp_path / "purejaxrl_ppo.py"
    script.write_text(section.split("```python\n", 1)[1].split("```", 1)[0])
    runpy.run_path(str(script), run_name="docs_example")
    printed = capsys.readouterr().out
    match = re.search(r"greedy mean return: ([\d.]+)", printed)
    assert match is not None, printed
    assert float(match[1]) >= 475.0
