"""The Gymnasium facade: registration, Env and VectorEnv contracts, wrappers, bad input."""

from __future__ import annotations

import dataclasses

import gymnasium as gym
import jax
import jax.numpy as jnp
import numpy as np
import pytest
import requires
from gymnasium.error import ResetNeeded
from gymnasium.utils.env_checker import check_env
from gymnasium.vector import AutoresetMode

import jaxenvs
from jaxenvs import registry
from jaxenvs.compat import gymnasium as facade
from jaxenvs.tasks import cartpole

SHORT = 5  # episode length of the short-episode fixtures
N = 4


def _make(gid: str, **kwargs):
    return gym.make(gid, **kwargs)


@pytest.fixture(scope="module")
def cartpole_env():
    env = _make("jaxenvs/CartPole-v0", render_mode="rgb_array", width=64, height=48)
    yield env
    env.close()


@pytest.fixture(scope="module")
def short_vec():
    envs = gym.make_vec(
        "jaxenvs/CartPole-v0",
        num_envs=N,
        vectorization_mode="vector_entry_point",
        max_episode_steps=SHORT,
    )
    yield envs
    envs.close()


# ----------------------------------------------------------------------- registration
def test_every_id_is_registered_with_gymnasium():
    for env_id in jaxenvs.list_envs():
        gspec = gym.spec(f"jaxenvs/{env_id}")
        ours = jaxenvs.spec(env_id)
        assert gspec.max_episode_steps == ours.config.episode_length
        assert gspec.reward_threshold == ours.reward_threshold
        assert gspec.vector_entry_point is not None
        assert gspec.kwargs == {"env_id": env_id}


def test_ids_registered_later_reach_gymnasium(monkeypatch):
    monkeypatch.setattr(registry, "_REGISTRY", dict(registry._REGISTRY))
    monkeypatch.setattr(gym.envs.registration, "registry", dict(gym.registry))
    config = cartpole.CartPoleConfig(episode_length=7)
    jaxenvs.register("LaterPole-v3", cartpole.CartPole, config, reward_threshold=6.0)
    gspec = gym.spec("jaxenvs/LaterPole-v3")
    assert (gspec.max_episode_steps, gspec.reward_threshold) == (7, 6.0)
    env = gym.make("jaxenvs/LaterPole-v3")
    assert env.unwrapped.jax_env.config.episode_length == 7
    env.close()


# --------------------------------------------------------------------------- one env
@pytest.mark.parametrize("env_id", ["CartPole-v0", "CartpoleBalance-v0"])
def test_passes_gymnasium_env_checker(env_id):
    env = _make(f"jaxenvs/{env_id}", render_mode="rgb_array", width=64, height=48)
    check_env(env.unwrapped, skip_render_check=False)
    frame = env.unwrapped.render()
    assert frame.shape == (48, 64, 3) and frame.dtype == np.uint8
    env.close()


@pytest.mark.full
@pytest.mark.parametrize("env_id", jaxenvs.list_envs())
def test_every_id_passes_env_checker(env_id):
    env = _make(f"jaxenvs/{env_id}", render_mode="rgb_array", width=64, height=48)
    check_env(env.unwrapped, skip_render_check=False)
    env.close()


def test_step_returns_numpy_and_python_scalars(cartpole_env):
    obs, info = cartpole_env.reset(seed=0)
    assert isinstance(obs, np.ndarray) and obs.dtype == np.float32 and obs.shape == (4,)
    assert info == {}
    obs, reward, terminated, truncated, info = cartpole_env.step(1)
    assert isinstance(obs, np.ndarray) and obs.dtype == np.float32
    assert obs.flags.writeable
    assert type(reward) is float and reward == 1.0
    assert type(terminated) is bool and type(truncated) is bool
    assert info == {"nan_actions": 0, "diverged": False}


def test_seeding_follows_gymnasium(cartpole_env):
    a, _ = cartpole_env.reset(seed=11)
    b, _ = cartpole_env.reset(seed=11)
    c, _ = cartpole_env.reset(seed=12)
    np.testing.assert_array_equal(a, b)
    assert not np.array_equal(a, c)
    cartpole_env.reset(seed=5)
    unseeded = [cartpole_env.reset()[0] for _ in range(2)]
    cartpole_env.reset(seed=5)
    again = [cartpole_env.reset()[0] for _ in range(2)]
    np.testing.assert_array_equal(np.stack(unseeded), np.stack(again))
    assert not np.array_equal(unseeded[0], unseeded[1])


def test_matches_the_functional_api(cartpole_env):
    cartpole_env.reset(seed=3)
    raw = cartpole_env.unwrapped
    state = raw.state
    step = jax.jit(raw.jax_env.step)
    for action in (1, 1, 0, 1):
        state = step(state, jnp.asarray(action, jnp.int32))
        obs, reward, terminated, truncated, _ = cartpole_env.step(action)
        np.testing.assert_allclose(obs, np.asarray(state.obs), rtol=1e-6, atol=1e-6)
        assert reward == float(state.reward) and terminated == bool(state.terminated)


def test_single_env_state_round_trips_bit_for_bit(cartpole_env):
    """The single env's word buffers hold every leaf exactly: integers and key data whose
    bits read as float32 NaNs or denormals, bools, and the state the env steps from."""
    cartpole_env.reset(seed=1)
    raw = cartpole_env.unwrapped
    words = raw._words
    state = raw.state
    odd = np.array([0x7F800001, 0x00000001], np.uint32)  # a signalling NaN, a denormal
    state = state.replace(
        key=jax.random.wrap_key_data(odd, impl=jax.random.key_impl(state.key)),
        time=jnp.asarray(np.array(0x7FC00001, np.uint32).view(np.int32)),
        terminated=jnp.asarray(True),
    )
    back = jax.jit(words.unpack)(jax.jit(words.pack)(state))
    for a, b in zip(jax.tree.leaves(state), jax.tree.leaves(back), strict=True):
        if jax.dtypes.issubdtype(a.dtype, jax.dtypes.prng_key):
            a, b = jax.random.key_data(a), jax.random.key_data(b)
        assert a.dtype == b.dtype
        bits = [np.asarray(x).reshape(-1).view(np.uint8) for x in (a, b)]
        np.testing.assert_array_equal(*bits)


@pytest.mark.parametrize("env_id", ["CartPole-v0", "Reacher-v0"])
def test_single_env_buffers_stay_small(env_id):
    """Every buffer of the single env's state fits XLA's sequential limit, so its step
    runs on the calling thread; the report sits in the first buffer(s)."""
    env = gym.make(f"jaxenvs/{env_id}")
    env.reset(seed=0)
    bufs = env.unwrapped._bufs
    assert all(b.nbytes <= facade.SEQUENTIAL_BYTES for b in bufs)
    assert len(bufs) <= 1 + sum(b.nbytes for b in bufs) // facade.SEQUENTIAL_BYTES + 1
    obs, reward, terminated, truncated, info = env.step(env.action_space.sample())
    state = env.unwrapped.state
    np.testing.assert_array_equal(obs, np.asarray(state.obs))
    assert reward == float(state.reward) and terminated == bool(state.terminated)
    assert truncated == bool(state.truncated)
    assert info["nan_actions"] == int(state.info["nan_actions"])
    assert isinstance(info["nan_actions"], int) and isinstance(info["diverged"], bool)
    env.close()


def test_instances_share_compiled_functions(cartpole_env):
    other = gym.make("jaxenvs/CartPole-v0")
    assert other.unwrapped._fns is cartpole_env.unwrapped._fns
    different = gym.make("jaxenvs/CartPole-v0", force=5.0)
    assert different.unwrapped._fns is not cartpole_env.unwrapped._fns
    assert different.unwrapped.jax_env.config.force == 5.0


@pytest.mark.parametrize(
    "action, match",
    [
        (2, r"out of range for Discrete\(2\)"),
        (-1, r"out of range for Discrete\(2\)"),
        (1.0, r"integer action in Discrete\(2\)"),
        (np.array([1]), r"Discrete\(2\).*shape \(\)"),
        (True, "bool"),
        ("left", r"Discrete\(2\)"),
    ],
)
def test_bad_discrete_actions_raise_before_jax(cartpole_env, action, match):
    raw = cartpole_env.unwrapped
    raw.reset(seed=0)
    fns = raw._fns

    def must_not_run(*args):
        raise AssertionError("reached JAX")

    raw._fns = dataclasses.replace(fns, step=must_not_run)
    try:
        with pytest.raises(ValueError, match=match):
            raw.step(action)
    finally:
        raw._fns = fns


@pytest.mark.parametrize(
    "action, match",
    [
        (np.zeros(2, np.float32), r"Box\(-1.0, 1.0, \(1,\), float32\).*shape \(2,\)"),
        (np.zeros((), np.float32), r"shape \(\)"),
        (np.array([1]), "floating-point action"),
    ],
)
def test_bad_continuous_actions_raise(action, match):
    env = gym.make("jaxenvs/CartpoleBalance-v0").unwrapped
    env.reset(seed=0)
    with pytest.raises(ValueError, match=match):
        env.step(action)
    obs, *_ = env.step(np.array([0.5], np.float64))  # float64 is accepted
    assert obs.dtype == np.float32


def test_order_enforcing_and_close():
    raw = facade.JaxEnv("CartPole-v0")
    with pytest.raises(ResetNeeded):
        raw.step(0)
    wrapped = gym.make("jaxenvs/CartPole-v0", render_mode="rgb_array")
    with pytest.raises(ResetNeeded):
        wrapped.step(0)
    with pytest.raises(ResetNeeded):
        wrapped.render()
    wrapped.reset(seed=0)
    wrapped.render()
    wrapped.close()
    wrapped.close()
    raw.close()
    raw.close()


def test_render_modes(monkeypatch):
    with pytest.raises(ValueError, match=r"'ansi'.*supported: \['rgb_array'\]"):
        gym.make("jaxenvs/CartPole-v0", render_mode="ansi")
    monkeypatch.delenv("DISPLAY", raising=False)
    monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)
    with pytest.raises(ValueError, match="needs a display"):
        gym.make("jaxenvs/CartPole-v0", render_mode="human")
    with pytest.raises(ValueError, match="rgb_array"):
        gym.make_vec("jaxenvs/CartPole-v0", 2, "vector_entry_point", render_mode="text")
    env = gym.make("jaxenvs/CartPole-v0")
    env.reset(seed=0)
    with pytest.warns(UserWarning, match="render_mode"):
        assert env.render() is None


def test_reset_options_are_checked(cartpole_env):
    cartpole_env.reset(options={})
    with pytest.raises(ValueError, match="unsupported reset options"):
        cartpole_env.reset(options={"target": 1})


# ------------------------------------------------------------------------- wrappers
def test_time_limit_and_episode_statistics():
    env = gym.wrappers.RecordEpisodeStatistics(gym.make("jaxenvs/CartPole-v0", max_episode_steps=3))
    env.reset(seed=0)
    for t in range(3):
        _, _, terminated, truncated, info = env.step(t % 2)
    assert truncated and not terminated
    assert info["episode"]["l"] == 3 and info["episode"]["r"] == 3.0


def test_normalize_observation():
    env = gym.wrappers.NormalizeObservation(gym.make("jaxenvs/CartPole-v0"))
    obs, _ = env.reset(seed=0)
    for _ in range(5):
        obs, *_ = env.step(1)
    assert obs.shape == (4,) and np.all(np.isfinite(obs))
    assert env.get_wrapper_attr("obs_rms").count > 1


def test_record_video(tmp_path):
    env = gym.make("jaxenvs/CartPole-v0", render_mode="rgb_array", width=64, height=48)
    env = gym.wrappers.RecordVideo(env, str(tmp_path), episode_trigger=lambda ep: ep == 0)
    env.reset(seed=0)
    done = False
    while not done:
        _, _, terminated, truncated, _ = env.step(int(env.action_space.sample()))
        done = terminated or truncated
    env.close()
    videos = list(tmp_path.glob("*.mp4"))
    assert len(videos) == 1 and videos[0].stat().st_size > 0


# ------------------------------------------------------------------------ vector env
def test_make_vec_is_one_batched_env(short_vec):
    raw = short_vec.unwrapped
    assert isinstance(raw, facade.JaxVectorEnv)
    assert isinstance(raw, gym.vector.VectorEnv)
    assert short_vec.metadata["autoreset_mode"] is AutoresetMode.SAME_STEP
    assert raw.jax_env.config.episode_length == SHORT  # from max_episode_steps
    assert short_vec.observation_space.shape == (N, 4)
    assert short_vec.single_action_space == gym.spaces.Discrete(2)
    calls = []
    step = raw._fns.step
    raw._fns = dataclasses.replace(raw._fns, step=lambda *a: calls.append(1) or step(*a))
    try:
        short_vec.reset(seed=0)
        obs, rewards, terminated, truncated, _ = short_vec.step(np.ones(N, np.int64))
    finally:
        raw._fns = dataclasses.replace(raw._fns, step=step)
    assert calls == [1]  # one jitted call for all envs
    assert obs.shape == (N, 4) and obs.dtype == np.float32
    assert rewards.shape == (N,) and terminated.dtype == np.bool_ and truncated.dtype == np.bool_


def test_same_step_autoreset_matches_sync_vector_env(short_vec):
    """Our infos have the structure SyncVectorEnv gives in SAME_STEP mode."""
    sync = gym.vector.SyncVectorEnv(
        [lambda: facade.JaxEnv("CartPole-v0", episode_length=SHORT)] * N,
        autoreset_mode=AutoresetMode.SAME_STEP,
    )
    ours = short_vec
    ours.reset(seed=1)
    sync.reset(seed=1)
    actions = np.array([1, 0, 1, 0])
    for _ in range(SHORT - 1):
        obs, _, terminated, truncated, info = ours.step(actions)
        sync.step(actions)
        assert "final_obs" not in info and not (terminated | truncated).any()
    prev_state = ours.unwrapped.state
    obs, _, terminated, truncated, info = ours.step(actions)
    _, _, s_term, s_trunc, s_info = sync.step(actions)
    assert truncated.all() and not terminated.any()
    assert sorted(info) == sorted(s_info)
    assert sorted(info["final_info"]) == sorted(s_info["final_info"])
    assert info["final_obs"].dtype == s_info["final_obs"].dtype == object
    np.testing.assert_array_equal(info["_final_obs"], s_info["_final_obs"])
    fin, s_fin = info["final_info"], s_info["final_info"]
    np.testing.assert_array_equal(fin["_diverged"], s_fin["_diverged"])
    np.testing.assert_array_equal(fin["nan_actions"], s_fin["nan_actions"])
    # final_obs is where the episode ended; obs is the fresh start of the next one
    env = ours.unwrapped.jax_env
    expected = jax.jit(jax.vmap(env.step))(prev_state, jnp.asarray(actions, jnp.int32)).obs
    for i in range(N):
        np.testing.assert_allclose(info["final_obs"][i], np.asarray(expected[i]), atol=1e-6)
        assert not np.allclose(obs[i], info["final_obs"][i])
    assert np.abs(obs).max() <= 0.05 + 1e-6  # fresh CartPole starts lie in +-0.05
    sync.close()


def test_reset_mask_resets_a_subset(short_vec):
    obs0, _ = short_vec.reset(seed=2)
    obs1, *_ = short_vec.step(np.ones(N, np.int64))
    mask = np.array([False, True, False, True])
    obs2, info = short_vec.reset(options={"reset_mask": mask})
    np.testing.assert_array_equal(obs2[~mask], obs1[~mask])
    assert not np.allclose(obs2[mask], obs1[mask])
    assert info == {}
    with pytest.raises(TypeError, match="numpy array"):
        short_vec.reset(options={"reset_mask": [True] * N})
    with pytest.raises(ValueError, match="shape"):
        short_vec.reset(options={"reset_mask": np.ones(N + 1, bool)})
    with pytest.raises(ValueError, match="at least one True"):
        short_vec.reset(options={"reset_mask": np.zeros(N, bool)})


def test_vector_seeding_and_bad_input(short_vec):
    a, _ = short_vec.reset(seed=9)
    b, _ = short_vec.reset(seed=9)
    np.testing.assert_array_equal(a, b)
    assert len({tuple(row) for row in a}) == N  # each env its own start
    with pytest.raises(ValueError, match=r"4 actions of Discrete\(2\)"):
        short_vec.step(np.ones(N + 1, np.int64))
    with pytest.raises(ValueError, match="out of range"):
        short_vec.step(np.array([0, 1, 2, 0]))
    fresh = facade.JaxVectorEnv("CartPole-v0", num_envs=N, episode_length=SHORT)
    with pytest.raises(ResetNeeded):
        fresh.step(np.ones(N, np.int64))
    fresh.close()
    fresh.close()


def test_vector_episode_statistics_wrapper(short_vec):
    envs = gym.wrappers.vector.RecordEpisodeStatistics(short_vec)
    envs.reset(seed=0)
    for _ in range(SHORT):
        *_, info = envs.step(np.ones(N, np.int64))
    assert info["_episode"].all()
    np.testing.assert_array_equal(info["episode"]["l"], np.full(N, SHORT))


# ----------------------------------------------------------------- Stable-Baselines3
@pytest.mark.full
def test_stable_baselines3_ppo_learns_cartpole():
    """The README's example: SB3's make_vec_env + PPO on the facade, evaluated greedily."""
    install = "pip install torch (a CPU build) and -e '.[bench-sb3]' (.ci/run does)"
    sb3 = requires.package("stable_baselines3", install)
    torch = requires.package("torch", install)

    torch.set_num_threads(1)
    from stable_baselines3.common.env_util import make_vec_env
    from stable_baselines3.common.evaluation import evaluate_policy

    venv = make_vec_env("jaxenvs/CartPole-v0", n_envs=4, seed=0)
    model = sb3.PPO("MlpPolicy", venv, seed=0, verbose=0).learn(total_timesteps=40_000)
    mean, _ = evaluate_policy(model, gym.make("jaxenvs/CartPole-v0"), n_eval_episodes=5)
    assert mean >= 400.0
