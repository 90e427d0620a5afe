"""The Gymnasium facade: registration, Env and VectorEnv contracts, wrappers, bad input."""

from __future__ import annotations

import copy
import dataclasses
import pickle

import gymnasium as gym
import jax
import jax.numpy as jnp
import numpy as np
import pytest
import requires
from gymnasium.error import ClosedEnvironmentError, ResetNeeded
from gymnasium.utils.env_checker import check_env
from gymnasium.vector import AutoresetMode
from host_devices import run_with_devices

import jaxenvs
from jaxenvs import registry
from jaxenvs.compat import gymnasium as facade
from jaxenvs.compat.gymnasium import programs
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


def test_single_env_report_reads_scalars_by_kind(cartpole_env):
    """One env's report reads every scalar of its first buffer in one go: the reward as
    a float, the flags and bool infos as bools, integer infos by their bits (a negative
    int32 stays negative)."""
    cartpole_env.reset(seed=2)
    raw = cartpole_env.unwrapped
    state = raw.state
    info = {**state.info, "nan_actions": jnp.asarray(-5, jnp.int32), "diverged": jnp.asarray(True)}
    state = state.replace(
        reward=jnp.asarray(0.25, jnp.float32), truncated=jnp.asarray(True), info=info
    )
    obs, reward, terminated, truncated, got = raw._words.report(jax.jit(raw._words.pack)(state))
    np.testing.assert_array_equal(obs, np.asarray(state.obs))
    assert (reward, terminated, truncated) == (0.25, False, True)
    assert got["nan_actions"] == -5 and type(got["nan_actions"]) is int
    assert got["diverged"] is True
    assert set(got) == set(raw._words._info_keys)


@pytest.mark.full
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


def _steps(env, actions):
    return [env.step(a) for a in actions]


def test_single_env_deep_copies_and_pickles():
    """A copy (deepcopy or pickle) of a started env goes on from the same state and seeding,
    apart from the original; an env not yet reset copies too."""
    env = gym.make("jaxenvs/CartpoleBalance-v0")
    env.reset(seed=3)
    env.step(np.array([0.5], np.float32))
    twin, packed = copy.deepcopy(env), pickle.loads(pickle.dumps(env))
    actions = [np.array([a], np.float32) for a in (1.0, -0.3, 0.7)]
    runs = [(_steps(e, actions), e.reset()[0]) for e in (twin, env, packed)]
    for steps, start in runs[1:]:
        np.testing.assert_array_equal(start, runs[0][1])  # the same np_random
        for a, b in zip(runs[0][0], steps, strict=True):
            np.testing.assert_array_equal(a[0], b[0])
            assert a[1:] == b[1:]
    assert twin.unwrapped._fns is env.unwrapped._fns  # the compiled functions are shared
    fresh = pickle.loads(pickle.dumps(gym.make("jaxenvs/CartPole-v0")))
    obs, _ = fresh.reset(seed=0)
    np.testing.assert_array_equal(obs, gym.make("jaxenvs/CartPole-v0").reset(seed=0)[0])


def test_a_closed_env_refuses_to_run():
    env = gym.make("jaxenvs/CartPole-v0", render_mode="rgb_array", width=32, height=24)
    env.reset(seed=0)
    env.close()
    for call in (lambda: env.step(0), env.reset, env.render):
        with pytest.raises(ClosedEnvironmentError, match="closed"):
            call()
    envs = _vec()
    envs.reset(seed=0)
    envs.close()
    with pytest.raises(ClosedEnvironmentError, match="closed"):
        envs.step(np.ones(N, np.int64))
    with pytest.raises(ClosedEnvironmentError, match="closed"):
        envs.reset(seed=0)


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
def _vec(mode=None, env_id="CartPole-v0", num_envs=N, **kwargs):
    extra = {} if mode is None else {"autoreset_mode": mode}
    return gym.make_vec(
        f"jaxenvs/{env_id}",
        num_envs=num_envs,
        vectorization_mode="vector_entry_point",
        max_episode_steps=SHORT,
        **extra,
        **kwargs,
    )


def _reference(mode, env_id="CartPole-v0", num_envs=N, **kwargs):
    """Gymnasium's own SyncVectorEnv over our single envs, in ``mode``."""
    return gym.vector.SyncVectorEnv(
        [lambda: facade.JaxEnv(env_id, episode_length=SHORT, **kwargs)] * num_envs,
        autoreset_mode=mode,
    )


def _copy_states(ours, ref, which):
    """Put our vector env's states of the envs in ``which`` into the reference's envs."""
    state = ours.unwrapped.state
    for i in np.flatnonzero(which):
        single = ref.envs[i]
        single._bufs = jax.jit(single._words.pack)(jax.tree.map(lambda x, i=i: x[i], state))


def _staggered(ours, ref, seed):
    """Reset both, then reset envs 1 and 3 again after two steps, so episodes end at
    different steps; the reference takes our states."""
    ours.reset(seed=seed)
    ref.reset(seed=seed)
    for _ in range(2):
        ours.step(np.ones(N, np.int64))
        ref.step(np.ones(N, np.int64))
    mask = np.array([False, True, False, True])
    ours.reset(options={"reset_mask": mask})
    ref.reset(options={"reset_mask": mask.copy()})
    _copy_states(ours, ref, np.ones(N, bool))


@pytest.mark.full
def test_make_vec_is_one_batched_env(short_vec):
    raw = short_vec.unwrapped
    assert isinstance(raw, facade.JaxVectorEnv)
    assert isinstance(raw, gym.vector.VectorEnv)
    assert short_vec.metadata["autoreset_mode"] is AutoresetMode.NEXT_STEP
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


@pytest.mark.parametrize(
    "given, mode",
    [
        ("same_step", AutoresetMode.SAME_STEP),
        ("SameStep", AutoresetMode.SAME_STEP),
        (AutoresetMode.DISABLED, AutoresetMode.DISABLED),
        ("next_step", AutoresetMode.NEXT_STEP),
    ],
)
def test_autoreset_mode_by_keyword(given, mode):
    envs = _vec(given)
    assert envs.metadata["autoreset_mode"] is mode
    envs.close()


@pytest.mark.parametrize("given", ["sometimes", 1, None])
def test_unknown_autoreset_mode_is_refused(given):
    with pytest.raises(ValueError, match=r"autoreset_mode must be .*next_step.*same_step"):
        facade.JaxVectorEnv("CartPole-v0", num_envs=2, autoreset_mode=given)


def _assert_steps_agree(ours, ref, resetting):
    """Our step equals the reference's, except the fresh starts of ``resetting`` envs."""
    o_obs, o_rew, o_term, o_trunc, o_info = ours
    r_obs, r_rew, r_term, r_trunc, r_info = ref
    np.testing.assert_array_equal(o_term, r_term)
    np.testing.assert_array_equal(o_trunc, r_trunc)
    np.testing.assert_allclose(o_rew, r_rew, atol=1e-6)
    assert o_rew.dtype == r_rew.dtype == np.float64
    np.testing.assert_allclose(o_obs[~resetting], r_obs[~resetting], atol=1e-5)
    assert sorted(o_info) == sorted(r_info)
    for key in r_info:
        if key.startswith("_"):
            np.testing.assert_array_equal(o_info[key], r_info[key])
        elif key not in ("final_obs", "final_info"):
            mask = r_info[f"_{key}"]
            assert o_info[key].dtype == r_info[key].dtype
            np.testing.assert_allclose(o_info[key][mask], r_info[key][mask], atol=1e-6)


def test_next_step_autoreset_matches_sync_vector_env():
    """NEXT_STEP: an env that ends at t returns its last obs at t; at t+1 its action is
    ignored and it returns a fresh start, reward 0, both flags False and no info."""
    ours, ref = _vec(), _reference(AutoresetMode.NEXT_STEP)
    _staggered(ours, ref, seed=4)
    ended = np.zeros(N, bool)
    seen_resets = 0
    rng = np.random.default_rng(0)
    for _ in range(3 * SHORT):
        actions = rng.integers(0, 2, N)
        out, expected = ours.step(actions), ref.step(actions)
        _assert_steps_agree(out, expected, resetting=ended)
        obs, rewards, terminated, truncated, info = out
        if ended.any():
            seen_resets += 1
            assert (rewards[ended] == 0).all() and not (terminated | truncated)[ended].any()
            assert np.abs(obs[ended]).max() <= 0.05 + 1e-6  # fresh CartPole starts
            for key in ("nan_actions", "diverged"):
                if key in info:
                    assert not info[f"_{key}"][ended].any()
            _copy_states(ours, ref, ended)
        ended = terminated | truncated
    assert seen_resets >= 3
    ours.close()
    ref.close()


@pytest.mark.full
def test_next_step_starts_where_same_step_starts():
    """A fresh start is drawn with the env's own key: NEXT_STEP's new episode starts, one
    step later, where SAME_STEP's does."""
    nxt, same = _vec(), _vec("same_step")
    nxt.reset(seed=8)
    same.reset(seed=8)
    actions = np.array([1, 0, 0, 1])
    for _ in range(SHORT):
        last_obs, _, _, truncated, _ = nxt.step(actions)
        fresh_obs, _, _, _, info = same.step(actions)
    assert truncated.all() and info["_final_obs"].all()
    np.testing.assert_allclose(np.stack(info["final_obs"]), last_obs, atol=1e-6)
    np.testing.assert_allclose(nxt.step(actions)[0], fresh_obs, atol=1e-6)
    nxt.close()
    same.close()


@pytest.mark.full  # two randomised vector programs
def test_randomized_next_step_draws_params_as_same_step():
    """With domain randomisation a NEXT_STEP reset draws new params, the ones SAME_STEP
    draws for the same env one step earlier."""
    nxt, same = _vec(randomize=True), _vec("same_step", randomize=True)
    nxt.reset(seed=3)
    same.reset(seed=3)
    first = nxt.unwrapped.state.params
    actions = np.ones(N, np.int64)
    for _ in range(SHORT):
        nxt.step(actions)
        same.step(actions)
    kept = nxt.unwrapped.state.params
    nxt.step(actions)  # resets every env
    drawn, reference = nxt.unwrapped.state.params, same.unwrapped.state.params
    first, kept, drawn, reference = (
        [np.asarray(x) for x in jax.tree.leaves(p)] for p in (first, kept, drawn, reference)
    )
    for a, b, c, d in zip(first, kept, drawn, reference, strict=True):
        np.testing.assert_array_equal(a, b)
        np.testing.assert_array_equal(c, d)
    assert any(not np.array_equal(a, c) for a, c in zip(first, drawn, strict=True))
    nxt.close()
    same.close()


@pytest.mark.full  # NEXT_STEP, the default, is in the default tier
def test_same_step_autoreset_matches_sync_vector_env():
    """SAME_STEP: an env that ends at t returns a fresh start at t; its last obs and info
    are in final_obs / final_info, with the structure SyncVectorEnv gives."""
    ours, ref = _vec("same_step"), _reference(AutoresetMode.SAME_STEP)
    _staggered(ours, ref, seed=5)
    rng = np.random.default_rng(1)
    ends = 0
    for _ in range(2 * SHORT):
        prev_state = ours.unwrapped.state
        actions = rng.integers(0, 2, N)
        out, expected = ours.step(actions), ref.step(actions)
        done = out[2] | out[3]
        _assert_steps_agree(out, expected, resetting=done)
        obs, info, s_info = out[0], out[4], expected[4]
        if not done.any():
            assert "final_obs" not in info
            continue
        ends += 1
        assert sorted(info["final_info"]) == sorted(s_info["final_info"])
        assert info["final_obs"].dtype == s_info["final_obs"].dtype == object
        env = ours.unwrapped.jax_env
        last = jax.jit(jax.vmap(env.step))(prev_state, jnp.asarray(actions, jnp.int32)).obs
        for i in range(N):
            if done[i]:
                np.testing.assert_allclose(info["final_obs"][i], s_info["final_obs"][i], atol=1e-5)
                np.testing.assert_allclose(info["final_obs"][i], np.asarray(last[i]), atol=1e-6)
                assert np.abs(obs[i]).max() <= 0.05 + 1e-6
            else:
                assert info["final_obs"][i] is None
        _copy_states(ours, ref, done)
    assert ends >= 2
    ours.close()
    ref.close()


@pytest.mark.full
def test_disabled_autoreset_matches_sync_vector_env():
    """DISABLED: no auto-reset; a finished env must be reset through reset_mask before
    the next step."""
    ours, ref = _vec("disabled"), _reference(AutoresetMode.DISABLED)
    _staggered(ours, ref, seed=6)
    rng = np.random.default_rng(2)
    resets = 0
    for _ in range(3 * SHORT):
        actions = rng.integers(0, 2, N)
        out, expected = ours.step(actions), ref.step(actions)
        _assert_steps_agree(out, expected, resetting=np.zeros(N, bool))
        done = out[2] | out[3]
        if done.any():
            resets += 1
            with pytest.raises(ResetNeeded, match="reset_mask"):
                ours.step(actions)
            kept = ours.unwrapped.state.obs
            obs, info = ours.reset(options={"reset_mask": done})
            ref.reset(options={"reset_mask": done.copy()})
            assert info == {}
            np.testing.assert_array_equal(obs[~done], np.asarray(kept)[~done])
            assert np.abs(obs[done]).max() <= 0.05 + 1e-6
            _copy_states(ours, ref, done)
    assert resets >= 3
    ours.close()
    ref.close()


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


def test_vector_reset_takes_a_seed_per_env(short_vec):
    """reset(seed=...) seeds the envs as Gymnasium's SyncVectorEnv seeds its own: a list
    gives one seed (or None) per env, an int s gives env i s + i; env i seeded with s
    starts where a single env's reset(seed=s) starts."""
    ref = _reference(AutoresetMode.NEXT_STEP)
    single = facade.JaxEnv("CartPole-v0", episode_length=SHORT)
    obs, info = short_vec.reset(seed=[0, 1, 2, 3])
    assert info == {}
    np.testing.assert_array_equal(obs, ref.reset(seed=[0, 1, 2, 3])[0])
    for i in range(N):
        np.testing.assert_array_equal(obs[i], single.reset(seed=i)[0])
    np.testing.assert_array_equal(short_vec.reset(seed=7)[0], ref.reset(seed=7)[0])
    same, _ = short_vec.reset(seed=[5] * N)
    assert (same == same[0]).all()
    mixed, _ = short_vec.reset(seed=(0, None, 2, None))
    np.testing.assert_array_equal(mixed[[0, 2]], obs[[0, 2]])
    short_vec.step(np.ones(N, np.int64))
    kept = short_vec.unwrapped.state.obs
    mask = np.array([False, True, False, True])
    part, _ = short_vec.reset(seed=[10, 11, 12, 13], options={"reset_mask": mask})
    np.testing.assert_array_equal(part[~mask], np.asarray(kept)[~mask])
    np.testing.assert_array_equal(part[1], single.reset(seed=11)[0])
    for bad, match in [
        ([0, 1], "a list of 4 seeds"),
        ([0, -1, 2, 3], "non-negative"),
        (True, "non-negative"),
        ("seven", "non-negative"),
    ]:
        with pytest.raises(ValueError, match=match):
            short_vec.reset(seed=bad)
    ref.close()


def test_compiled_functions_cache_is_bounded(monkeypatch):
    monkeypatch.setattr(programs, "CACHE_SIZE", 2)
    monkeypatch.setattr(programs, "_CACHE", programs._CACHE.__class__())
    first = facade.compiled("CartPole-v0", {"force": 1.0})
    assert facade.compiled("CartPole-v0", {"force": 1.0}) is first
    facade.compiled("CartPole-v0", {"force": 2.0})
    facade.compiled("CartPole-v0", {"force": 3.0})
    assert len(programs._CACHE) == 2
    assert facade.compiled("CartPole-v0", {"force": 1.0}) is not first


_TWO_DEVICES = """
import numpy as np, gymnasium as gym, jaxenvs
runs = {}
for devices in (2, 1):
    envs = gym.make_vec("jaxenvs/CartPole-v0", num_envs=4, vectorization_mode="vector_entry_point",
                        max_episode_steps=5, devices=devices, physics="c")
    assert envs.unwrapped._fns.batched.devices == devices
    seq = [envs.reset(seed=0)[0]]
    for _ in range(12):
        obs, reward, *_ = envs.step(np.ones(4, np.int64))
        seq += [obs, np.repeat(reward[:, None], 4, 1)]
    seq.append(envs.reset(options={"reset_mask": np.array([True, False, True, False])})[0])
    runs[devices] = np.concatenate(seq)
np.testing.assert_array_equal(runs[2], runs[1])
"""


@pytest.mark.full  # a 2-device subprocess
def test_next_step_vector_env_spread_over_devices_is_bit_identical():
    run_with_devices(2, _TWO_DEVICES)


# ------------------------------------------------------------------ vector wrappers
def _episode_run(envs, steps, seed=0, actions=None):
    """Steps of ``envs`` (default NEXT_STEP), as lists of arrays, after reset(seed)."""
    obs, _ = envs.reset(seed=seed)
    out = {"obs": [obs], "reward": [], "done": [], "info": []}
    for t in range(steps):
        a = np.ones(envs.num_envs, np.int64) if actions is None else actions[t]
        obs, reward, terminated, truncated, info = envs.step(a)
        out["obs"].append(obs)
        out["reward"].append(reward)
        out["done"].append(terminated | truncated)
        out["info"].append(info)
    return out


def test_normalize_observation_vector_wrapper():
    steps = 2 * SHORT + 2
    envs = gym.wrappers.vector.NormalizeObservation(_vec(), epsilon=1e-8)
    raw = _episode_run(_vec(), steps)
    got = _episode_run(envs, steps)
    seen = np.concatenate(raw["obs"])
    rms = envs.obs_rms
    np.testing.assert_allclose(rms.mean, seen.mean(axis=0), rtol=1e-4, atol=1e-5)
    np.testing.assert_allclose(rms.count, len(seen) + 1e-4)
    expected = (raw["obs"][-1] - rms.mean) / np.sqrt(rms.var + 1e-8)
    np.testing.assert_allclose(got["obs"][-1], expected, rtol=1e-4, atol=1e-4)


def test_transform_and_dtype_observation_vector_wrappers():
    steps = SHORT + 2
    raw = _episode_run(_vec(), steps)
    doubled = gym.wrappers.vector.TransformObservation(_vec(), lambda obs: 2 * obs)
    as64 = gym.wrappers.vector.DtypeObservation(_vec(), np.float64)
    np.testing.assert_array_equal(
        np.stack(_episode_run(doubled, steps)["obs"]), 2 * np.stack(raw["obs"])
    )
    got64 = np.stack(_episode_run(as64, steps)["obs"])
    assert got64.dtype == np.float64
    np.testing.assert_array_equal(got64, np.stack(raw["obs"]))


def test_reward_vector_wrappers_see_next_step_rewards():
    """CartPole pays 1 a step and, under NEXT_STEP, 0 on the step that resets an env:
    NormalizeReward and ClipReward give what they give over SyncVectorEnv."""
    steps = 3 * SHORT
    for wrap in (
        lambda e: gym.wrappers.vector.NormalizeReward(e, gamma=0.9),
        lambda e: gym.wrappers.vector.ClipReward(e, 0.0, 0.5),
    ):
        got = _episode_run(wrap(_vec()), steps)
        ref = _episode_run(wrap(_reference(AutoresetMode.NEXT_STEP)), steps)
        np.testing.assert_allclose(np.stack(got["reward"]), np.stack(ref["reward"]), rtol=1e-6)
        assert (np.stack(got["reward"])[SHORT] == 0).all()  # the reset step


@pytest.mark.full
def test_clip_action_vector_wrapper():
    """Out-of-range actions through ClipAction step as their clipped values do; the step
    after the episodes end resets them (reward 0)."""
    steps = SHORT + 2
    rng = np.random.default_rng(3)
    big = [rng.uniform(-3, 3, (N, 2)).astype(np.float32) for _ in range(steps)]
    clipped = [np.clip(a, -1, 1) for a in big]
    wrapped = gym.wrappers.vector.ClipAction(_vec(None, "Reacher-v0", physics="c"))
    got = _episode_run(wrapped, steps, actions=big)
    ref = _episode_run(_vec(None, "Reacher-v0", physics="c"), steps, actions=clipped)
    np.testing.assert_array_equal(np.stack(got["obs"]), np.stack(ref["obs"]))
    assert (np.stack(got["reward"])[SHORT] == 0).all()  # the reset step


def test_record_episode_statistics_vector_wrapper():
    """Recorded returns and lengths are each episode's summed step rewards and steps
    (Reacher: rewards vary from step to step)."""
    base = _vec(None, "Reacher-v0", physics="c")
    envs = gym.wrappers.vector.RecordEpisodeStatistics(base)
    envs.reset(seed=0)
    rng = np.random.default_rng(4)
    sums, lengths, resetting = np.zeros(N), np.zeros(N, int), np.zeros(N, bool)
    recorded = 0
    for _ in range(3 * SHORT):
        action = rng.uniform(-1, 1, (N, 2)).astype(np.float32)
        _, reward, terminated, truncated, info = envs.step(action)
        sums = np.where(resetting, 0.0, sums + reward)
        lengths = np.where(resetting, 0, lengths + 1)
        done = terminated | truncated
        assert ("episode" in info) == done.any()
        if done.any():
            recorded += done.sum()
            np.testing.assert_array_equal(info["_episode"], done)
            np.testing.assert_allclose(info["episode"]["r"][done], sums[done], rtol=1e-6)
            np.testing.assert_array_equal(info["episode"]["l"][done], lengths[done])
        resetting = done
    assert recorded >= 2 * N


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
    # a seeded evaluation env, 20 episodes: an unseeded one's 5 episodes once averaged
    # 392.6 for a policy whose 20-episode means are 464-476 under seeds 0-2
    eval_env = gym.make("jaxenvs/CartPole-v0")
    eval_env.reset(seed=0)
    mean, _ = evaluate_policy(model, eval_env, n_eval_episodes=20)
    assert mean >= 400.0
