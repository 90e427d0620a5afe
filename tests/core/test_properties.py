"""Property-based tests (hypothesis): action spaces and sanitisation, the tabular
discretiser, GAE, config parsing and the Gymnasium facade's input validation.

Every jitted function is compiled once for a fixed shape and fed many examples; the
pure-Python properties get more examples than the jitted ones.
"""

from __future__ import annotations

import dataclasses
import typing

import jax
import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp

import jaxenvs
from jaxenvs.agents import losses, ppo, tabular
from jaxenvs.compat import gymnasium as facade
from jaxenvs.config import ConfigError, apply_overrides, config_to_dict

FAST = settings(max_examples=150, deadline=None)
JITTED = settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.too_slow])

any_float = st.floats(allow_nan=True, allow_infinity=True, width=32)
finite = st.floats(-1e6, 1e6, allow_nan=False, width=32)


@pytest.fixture(scope="module")
def envs():
    return jaxenvs.make("CartpoleBalance-v0"), jaxenvs.make("CartPole-v0")


@pytest.fixture(scope="module")
def sanitize(envs):
    cont, disc = envs
    return jax.jit(cont.sanitize_action), jax.jit(disc.sanitize_action)


# ------------------------------------------------------------------ spaces, actions
@JITTED
@given(x=any_float)
def test_any_float_action_lands_in_the_box(envs, sanitize, x):
    cont, _ = envs
    action, bad = sanitize[0](np.array([x], np.float32))
    action = np.asarray(action)
    assert cont.action_space.contains(action)
    assert int(bad) == int(not np.isfinite(x))
    expected = 0.0 if not np.isfinite(x) else float(np.clip(np.float32(x), -1, 1))
    if abs(np.float32(expected)) < np.finfo(np.float32).tiny:
        # XLA on CPU flushes float32 subnormals (|x| < 1.2e-38) to zero
        assert action[0] in (np.float32(expected), np.float32(0.0))
    else:
        assert action[0] == np.float32(expected)


@JITTED
@given(a=st.integers(-(2**31), 2**31 - 1))
def test_any_int_action_lands_in_discrete(envs, sanitize, a):
    _, disc = envs
    action, bad = sanitize[1](np.int32(a))
    assert disc.action_space.contains(int(action)) and int(bad) == 0
    assert int(action) == min(max(a, 0), disc.action_size - 1)


# ---------------------------------------------------------------------- discretiser
DIM = 3
BIG = float(np.float32(1e30))


@pytest.fixture(scope="module")
def disc_fns():
    both = jax.vmap(lambda d, o: (tabular.bin_index(d, o), tabular.state_index(d, o)), (None, 0))
    return jax.jit(both)


@JITTED
@given(
    low=hnp.arrays(np.float32, DIM, elements=st.floats(-100, 100, width=32)),
    width=hnp.arrays(np.float32, DIM, elements=st.floats(0.0625, 100, width=32)),
    splits=st.tuples(*[st.integers(1, 12)] * DIM),
    obs=hnp.arrays(
        np.float32,
        (8, DIM),
        elements=st.floats(-BIG, BIG, allow_nan=False, width=32)
        | st.sampled_from([np.float32(np.inf), np.float32(-np.inf)]),
    ),
)
def test_discretiser_indices_are_in_range_and_monotone(disc_fns, low, width, splits, obs):
    high = low + width
    disc = tabular.make_discretiser(tuple(low.tolist()), tuple(high.tolist()), splits)
    bins, rows = map(np.asarray, disc_fns(disc, obs))
    assert np.all(bins >= 0) and np.all(bins < np.array(splits))
    assert np.all(rows >= 0) and np.all(rows < disc.num_states)
    # row-major: the row decodes back to the per-dimension bins
    np.testing.assert_array_equal(np.stack(np.unravel_index(rows, splits), 1), bins)
    # monotone in every coordinate (sorting the batch per dimension keeps bins sorted)
    sorted_bins = np.asarray(disc_fns(disc, np.sort(obs, axis=0))[0])
    assert np.all(np.diff(sorted_bins, axis=0) >= 0)


# ------------------------------------------------------------------------------ GAE
T, B = 7, 3


def _gae_reference(r, v, nv, term, done, gamma, lam):
    adv = np.zeros_like(r, np.float64)
    nxt = np.zeros(r.shape[1])
    for t in reversed(range(r.shape[0])):
        delta = r[t] + gamma * (1 - term[t]) * nv[t] - v[t]
        nxt = delta + gamma * lam * (1 - done[t]) * nxt
        adv[t] = nxt
    return adv, adv + v


@pytest.fixture(scope="module")
def gae_fn():
    return jax.jit(losses.gae)


@JITTED
@given(
    r=hnp.arrays(np.float32, (T, B), elements=st.floats(-10, 10, width=32)),
    v=hnp.arrays(np.float32, (T, B), elements=st.floats(-10, 10, width=32)),
    nv=hnp.arrays(np.float32, (T, B), elements=st.floats(-10, 10, width=32)),
    term=hnp.arrays(np.bool_, (T, B)),
    trunc=hnp.arrays(np.bool_, (T, B)),
    gamma=st.floats(0, 1),
    lam=st.floats(0, 1),
)
def test_gae_matches_the_reference_recursion(gae_fn, r, v, nv, term, trunc, gamma, lam):
    done = term | trunc
    adv, ret = map(np.asarray, gae_fn(r, v, nv, term, done, gamma, lam))
    ref_adv, ref_ret = _gae_reference(r, v, nv, term, done, gamma, lam)
    np.testing.assert_allclose(adv, ref_adv, rtol=1e-4, atol=1e-3)
    np.testing.assert_allclose(ret, ref_ret, rtol=1e-4, atol=1e-3)
    # the last step of an episode never looks past it: its advantage is its own delta
    last = done | (np.arange(T) == T - 1)[:, None]
    delta = r + gamma * (1 - term) * nv - v
    np.testing.assert_allclose(adv[last], delta[last], rtol=1e-4, atol=1e-3)


# ------------------------------------------------------------------ config parsing
PPO_FIELDS = {f.name: f for f in dataclasses.fields(ppo.PPOConfig)}
json_values = st.recursive(
    st.none() | st.booleans() | st.integers() | st.floats(allow_nan=False) | st.text(max_size=5),
    lambda inner: st.lists(inner, max_size=3) | st.dictionaries(st.text(max_size=3), inner),
    max_leaves=5,
)


@FAST
@given(
    key=st.text(min_size=1, max_size=12).filter(lambda k: k not in PPO_FIELDS), value=json_values
)
def test_unknown_keys_are_named_with_the_source(key, value):
    with pytest.raises(ConfigError) as err:
        apply_overrides(ppo.PPOConfig(), {key: value}, "flags.yaml")
    assert repr(key) in str(err.value) and "flags.yaml" in str(err.value)
    assert "valid keys" in str(err.value)


def _valid_values(key: str) -> list[object]:
    """Values of ``key`` any PPO config accepts: the default as JSON gives it, and for a
    number the default scaled a little (every numeric PPO field is a positive size, rate
    or bound)."""
    default = config_to_dict(ppo.PPOConfig())[key]
    if isinstance(default, bool) or not isinstance(default, int | float):
        return [default]
    if isinstance(default, int):
        return [default, default * 2]
    return [default, min(default * 1.5, 1.0) if 0 < default <= 1 else default * 1.5]


@pytest.mark.parametrize("key", sorted(PPO_FIELDS))
def test_every_field_accepts_valid_values(key):
    """The refusals below are meaningful only because the same parser accepts these."""
    for value in _valid_values(key):
        new = apply_overrides(ppo.PPOConfig(), {key: value}, "cli")
        assert getattr(new, key) == (tuple(value) if isinstance(value, list) else value)


def _json_type_fits(value: object, default: object) -> bool:
    """Whether ``value`` (from JSON) has the type a field with ``default`` declares."""
    if isinstance(default, bool):
        return isinstance(value, bool)
    if isinstance(default, float):
        return isinstance(value, int | float) and not isinstance(value, bool)
    if isinstance(default, int):
        return isinstance(value, int) and not isinstance(value, bool)
    if isinstance(default, str):
        return isinstance(value, str)
    return True


@FAST
@given(key=st.sampled_from(sorted(PPO_FIELDS)), value=json_values)
def test_any_value_is_accepted_typed_or_refused_by_name(key, value):
    default = getattr(ppo.PPOConfig(), key)
    try:
        new = apply_overrides(ppo.PPOConfig(), {key: value}, "cli")
    except ConfigError as err:
        assert repr(key) in str(err) and "cli" in str(err)
        # a valid value is never refused (compared with its type: True == 1.0 in Python)
        valid = _valid_values(key)
        assert not any(type(v) is type(value) and v == value for v in valid), (key, value)
        return
    # accepted: the value had the declared type, the field has it, the config validates
    assert _json_type_fits(value, default), (key, value)
    got = getattr(new, key)
    assert type(got) is type(default) or (isinstance(default, float) and type(got) is float)
    if isinstance(default, tuple):  # tuple[int, ...] or tuple[str, ...]: elements of it
        (element, _) = typing.get_args(typing.get_type_hints(ppo.PPOConfig)[key])
        assert all(type(x) is element for x in got), (key, got)
    new.validate()


@FAST
@given(
    num_envs=st.integers(1, 64),
    num_steps=st.integers(1, 64),
    num_minibatches=st.sampled_from([1, 2, 4]),
    gamma=st.floats(0, 1),
    hidden=st.lists(st.integers(1, 256), min_size=0, max_size=3),
)
def test_config_round_trips_through_its_dict(num_envs, num_steps, num_minibatches, gamma, hidden):
    overrides = {
        "num_envs": num_envs * num_minibatches,
        "num_steps": num_steps,
        "num_minibatches": num_minibatches,
        "gamma": gamma,
        "actor_hidden": hidden,
    }
    config = apply_overrides(ppo.PPOConfig(), overrides, "test")
    again = apply_overrides(ppo.PPOConfig(), config_to_dict(config), "round trip")
    assert again == config


# --------------------------------------------------------------- facade validation
shapes = hnp.array_shapes(min_dims=0, max_dims=3, min_side=0, max_side=4)
dtypes = st.sampled_from(
    [np.float32, np.float64, np.float16, np.int32, np.int64, np.uint8, np.bool_]
)


@FAST
@given(data=st.data(), num_envs=st.sampled_from([None, 2]))
def test_facade_accepts_exactly_the_space_or_names_it(envs, data, num_envs):
    for env in envs:
        shape = data.draw(
            shapes | st.just((*(() if num_envs is None else (num_envs,)), *env.action_shape))
        )
        dtype = data.draw(dtypes)
        action = data.draw(hnp.arrays(dtype, shape))
        expected = (*(() if num_envs is None else (num_envs,)), *env.action_shape)
        try:
            out = facade.check_action(env, action, num_envs)
        except ValueError as err:
            assert str(env.action_space) in str(err)
            continue
        assert out.shape == expected
        if env.discrete:
            assert np.issubdtype(action.dtype, np.integer) and action.dtype != np.bool_
            assert out.dtype == np.int32 and np.all((out >= 0) & (out < env.action_size))
        else:
            assert np.issubdtype(action.dtype, np.floating) and out.dtype == np.float32
