"""Domain randomisation: the sampling helpers and every task's ``sample_params``.

Task-level checks run on one env id per robot family: Reacher-v0 and CartpoleBalance-v0
(the cartpole configs share one randomisation base, checked for all four ids cheaply).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import jaxenvs
from jaxenvs import randomize
from jaxenvs.config import ConfigError
from jaxenvs.core import BatchedEnv

# ---------------------------------------------------------------------------- helpers


def test_check_range_accepts_and_rejects():
    randomize.check_range("r", (0.5, 2.0), positive=True)
    randomize.check_range("r", (1.0, 1.0), positive=True)
    with pytest.raises(ConfigError, match="'r'.*low <= high"):
        randomize.check_range("r", (2.0, 0.5))
    with pytest.raises(ConfigError, match="low > 0"):
        randomize.check_range("r", (0.0, 1.0), positive=True)
    with pytest.raises(ConfigError, match="high <= 0.2"):
        randomize.check_range("r", (0.1, 0.3), max_high=0.2)
    with pytest.raises(ConfigError, match="low >= 0"):
        randomize.check_range("r", (-0.1, 0.3), min_low=0.0)


def test_uniform_respects_range_and_covers_it():
    x = np.asarray(randomize.uniform(jax.random.key(0), (0.5, 1.5), (10_000,)))
    assert x.min() >= 0.5 and x.max() <= 1.5
    assert x.min() < 0.51 and x.max() > 1.49
    assert abs(x.mean() - 1.0) < 0.02
    assert np.all(np.asarray(randomize.uniform(jax.random.key(1), (0.3, 0.3), (5,))) == 0.3)


def test_scale_is_per_row_and_masked():
    value = jnp.array([[2.0, 4.0], [1.0, 3.0], [5.0, 5.0]])
    mask = jnp.array([True, True, False])
    out = np.asarray(randomize.scale(jax.random.key(0), value, (0.5, 2.0), mask))
    ratio = out[:2] / np.asarray(value[:2])
    assert np.allclose(ratio[:, 0], ratio[:, 1])  # one factor per row
    assert np.all((ratio >= 0.5) & (ratio <= 2.0))
    assert not np.isclose(ratio[0, 0], ratio[1, 0])  # independent rows
    np.testing.assert_array_equal(out[2], [5.0, 5.0])  # masked row untouched


def test_offset_adds_within_range():
    value = jnp.zeros(1000)
    out = np.asarray(randomize.offset(jax.random.key(0), value, (0.1, 0.2)))
    assert out.min() >= 0.1 and out.max() <= 0.2 and out.std() > 0.01


def test_scale_mass_scales_mass_and_inertia_together():
    mass = jnp.array([0.0, 1.0, 0.1])
    inertia = jnp.array([[0.0, 0.0, 0.0], [0.01, 0.02, 0.03], [0.008, 0.008, 1e-5]])
    m, i = randomize.scale_mass(jax.random.key(0), mass, inertia, (0.5, 1.5))
    f = np.asarray(m)[1:] / np.asarray(mass)[1:]
    np.testing.assert_allclose(np.asarray(i)[1:] / np.asarray(inertia)[1:], f[:, None] * [1, 1, 1])
    assert np.all((f >= 0.5) & (f <= 1.5))


def test_scale_fields_draw_does_not_depend_on_other_fields():
    fields = {"a": jnp.ones(3), "b": jnp.ones(3), "c": jnp.ones(3)}
    key = jax.random.key(4)
    both = randomize.scale_fields(key, fields, {"a": (0.5, 1.5), "b": (0.5, 1.5)})
    one = randomize.scale_fields(key, fields, {"b": (0.5, 1.5)})
    np.testing.assert_array_equal(np.asarray(both["b"]), np.asarray(one["b"]))
    assert not np.allclose(np.asarray(both["a"]), np.asarray(both["b"]))
    np.testing.assert_array_equal(np.asarray(both["c"]), np.ones(3))
    with pytest.raises(KeyError, match="no model field"):
        randomize.scale_fields(key, fields, {"body_mass": (0.5, 1.5)})


def test_uniforms_are_slices_of_one_draw_within_their_ranges():
    key = jax.random.key(2)
    a, b, c = randomize.uniforms(key, [((0.5, 1.5), (4,)), ((-1.0, 0.0), (2, 3)), ((2, 2), ())])
    assert a.shape == (4,) and b.shape == (2, 3) and c.shape == ()
    u = np.asarray(jax.random.uniform(key, (11,)))
    np.testing.assert_allclose(np.asarray(a), 0.5 + u[:4], rtol=1e-6)
    np.testing.assert_allclose(np.asarray(b).ravel(), -1.0 + u[4:10], rtol=1e-6, atol=1e-7)
    assert float(c) == 2.0
    # a draw does not depend on the draws after it
    (first,) = randomize.uniforms(key, [((0.5, 1.5), (4,))])
    np.testing.assert_array_equal(np.asarray(first), np.asarray(a))
    big = np.concatenate(
        [
            np.asarray(x).ravel()
            for x in randomize.uniforms(jax.random.key(3), [((0, 1), (5000,))] * 2)
        ]
    )
    assert abs(big.mean() - 0.5) < 0.02 and big.min() >= 0 and big.max() <= 1


def test_batched_randomised_reset_is_the_envs_reset_with_drawn_params():
    benv = jaxenvs.make("CartPole-v0", num_envs=4, randomize=True)
    key = jax.random.key(7)
    s = jax.jit(benv.reset)(key)
    keys = jax.random.split(key, 4)
    want = jax.jit(jax.vmap(benv.env.reset))(keys, s.params)
    for got, ref in zip(jax.tree.leaves(s.obs), jax.tree.leaves(want.obs), strict=True):
        np.testing.assert_array_equal(np.asarray(got), np.asarray(ref))
    np.testing.assert_array_equal(
        np.asarray(jax.random.key_data(s.key)), np.asarray(jax.random.key_data(want.key))
    )
    drawn = jax.vmap(benv.env.sample_params)(jax.vmap(lambda k: jax.random.split(k, 4)[3])(keys))
    for got, ref in zip(jax.tree.leaves(s.params), jax.tree.leaves(drawn), strict=True):
        np.testing.assert_array_equal(np.asarray(got), np.asarray(ref))


# ------------------------------------------------------------------------------ tasks

CARTPOLE_IDS = ["CartPole-v0", "CartpoleStayUp-v0", "CartpoleBalance-v0", "CartpoleSwingup-v0"]


def _ratios(params, default, name):
    new = np.asarray(params.model[name])
    old = np.asarray(default.model[name])
    nz = old != 0
    return new[..., nz] / old[nz], new[..., ~nz]


@pytest.mark.full
@pytest.mark.parametrize("env_id", CARTPOLE_IDS)
def test_cartpole_ranges_respected(env_id):
    env = jaxenvs.make(env_id, mass_scale=(0.5, 0.6), damping_range=(0.2, 0.3), gain_scale=(2, 3))
    p = jax.vmap(env.sample_params)(jax.random.split(jax.random.key(0), 64))
    d = env.default_params
    mass, zero_mass = _ratios(p, d, "body_mass")
    assert np.all((mass >= 0.5 - 1e-6) & (mass <= 0.6 + 1e-6)) and mass.std() > 0.01
    assert np.all(zero_mass == 0)  # the world body stays massless
    inertia, _ = _ratios(p, d, "body_inertia")
    assert np.all((inertia >= 0.5 - 1e-6) & (inertia <= 0.6 + 1e-6))
    damping = np.asarray(p.model["dof_damping"]) - np.asarray(d.model["dof_damping"])
    assert np.all((damping >= 0.2 - 1e-6) & (damping <= 0.3 + 1e-6))
    gain, _ = _ratios(p, d, "actuator_gear")
    assert np.all((gain >= 2 - 1e-5) & (gain <= 3 + 1e-5))


def test_reacher_ranges_respected():
    env = jaxenvs.make(
        "Reacher-v0",
        mass_scale=(0.5, 0.6),
        armature_scale=(1.5, 1.6),
        damping_scale=(0.1, 0.2),
        gain_scale=(3, 4),
        target_radius_range=(0.05, 0.1),
    )
    p = jax.vmap(env.sample_params)(jax.random.split(jax.random.key(0), 64))
    d = env.default_params
    for name, (lo, hi) in [
        ("body_mass", (0.5, 0.6)),
        ("body_inertia", (0.5, 0.6)),
        ("dof_armature", (1.5, 1.6)),
        ("dof_damping", (0.1, 0.2)),
        ("actuator_gear", (3, 4)),
    ]:
        ratio, _ = _ratios(p, d, name)
        if name.startswith("body"):  # the arm's links only; the mocap target keeps its mass
            ratio = ratio[:, :2] if name == "body_mass" else ratio[:, :6]
        assert np.all((ratio >= lo - 1e-5) & (ratio <= hi + 1e-5)), name
        assert ratio.std() > 1e-3, name
    np.testing.assert_array_equal(
        np.asarray(p.model["body_mass"])[:, -1], np.asarray(d.model["body_mass"])[-1]
    )
    r = np.asarray(p.target_radius)
    assert np.all((r >= 0.05) & (r <= 0.1)) and r.std() > 0.005


@pytest.mark.parametrize(
    "env_id, bad",
    [
        ("Reacher-v0", {"mass_scale": (1.2, 0.8)}),
        ("Reacher-v0", {"gain_scale": (0.0, 1.0)}),
        ("Reacher-v0", {"target_radius_range": (0.1, 0.3)}),
        ("CartpoleBalance-v0", {"damping_range": (-1.0, 0.0)}),
        ("CartPole-v0", {"mass_scale": (0.5,)}),
    ],
)
def test_bad_ranges_rejected_at_make(env_id, bad):
    with pytest.raises(ConfigError, match=next(iter(bad))):
        jaxenvs.make(env_id, **bad)


# ------------------------------------------------ randomised batched envs (compile once)

N = 8


@pytest.fixture(
    scope="module",
    params=[pytest.param("Reacher-v0", marks=pytest.mark.full), "CartpoleBalance-v0"],
)
def dr(request):
    """A single env and jitted functions that step N envs from ONE reset key with the
    same actions, once with per-env sampled params and once with the defaults."""
    env = jaxenvs.make(request.param, episode_length=1000)

    def run(key, params):
        reset_key, act_key = jax.random.split(key)
        state = jax.vmap(env.reset, in_axes=(None, 0))(reset_key, params)

        def body(s, k):
            a = jax.random.uniform(k, (env.action_size,), minval=-1.0, maxval=1.0)
            s = jax.vmap(env.step, in_axes=(0, None, 0))(s, a, params)
            return s, None

        state, _ = jax.lax.scan(body, state, jax.random.split(act_key, 30))
        return state

    return env, jax.jit(run)


@pytest.mark.full
def test_same_key_different_params_diverge(dr):
    env, run = dr
    params = jax.vmap(env.sample_params)(jax.random.split(jax.random.key(1), N))
    s = run(jax.random.key(2), params)
    qpos = np.asarray(s.data.qpos)
    spread = np.abs(qpos - qpos[0]).max(axis=1)
    assert np.all(spread[1:] > 1e-4), spread


def test_same_key_default_params_do_not_diverge(dr):
    env, run = dr
    params = jax.tree.map(lambda x: jnp.stack([x] * N), env.default_params)
    s = run(jax.random.key(2), params)
    qpos = np.asarray(s.data.qpos)
    np.testing.assert_array_equal(qpos, np.broadcast_to(qpos[0], qpos.shape))


@pytest.fixture(scope="module")
def reacher_batched():
    """Randomised and plain batched reachers with 5-step episodes."""
    on = jaxenvs.make("Reacher-v0", num_envs=N, randomize=True, episode_length=5)
    off = jaxenvs.make("Reacher-v0", num_envs=N, episode_length=5)
    assert isinstance(on, BatchedEnv) and isinstance(off, BatchedEnv)
    return on, off


@pytest.mark.full
def test_batched_randomize_gives_each_env_its_params(reacher_batched):
    on, off = reacher_batched
    s = jax.jit(on.reset)(jax.random.key(0))
    gear = np.asarray(s.params.model["actuator_gear"])[:, :, 0]
    assert gear.shape == (N, 2) and len(np.unique(gear[:, 0])) == N
    assert jax.jit(off.reset)(jax.random.key(0)).params is None


@pytest.mark.full
def test_params_fixed_in_episode_redrawn_at_reset(reacher_batched):
    on, _ = reacher_batched
    step = jax.jit(on.step)
    s = jax.jit(on.reset)(jax.random.key(0))
    zero = jnp.zeros((N, 2))
    gears = [np.asarray(s.params.model["actuator_gear"])]
    for _ in range(5):
        s = step(s, zero)
        gears.append(np.asarray(s.params.model["actuator_gear"]))
    # unchanged during the episode, redrawn for every env when it ends (step 5)
    for g in gears[1:5]:
        np.testing.assert_array_equal(g, gears[0])
    assert np.asarray(s.truncated).all()
    assert np.all(gears[5][:, 0, 0] != gears[0][:, 0, 0])
