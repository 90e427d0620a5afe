"""MuJoCo's C engine (``physics="c"``) under the functional API, for every task.

What these check: the engine switch (``auto`` resolution, the GPU refusal); that after a
C step every field a task reads holds what MJX gives after the same step (obs, reward,
termination and the task's metrics compared for EVERY registered task, so a task that
reads a field the C engine does not fill - those are NaN - fails here loudly); jit, nested
vmap, the auto-reset and determinism (bit-identical, whatever the thread count); per-env
params (domain randomisation) honoured; unknown params fields refused by name.
"""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import jaxenvs
from jaxenvs import machine
from jaxenvs.actions import random_actions
from jaxenvs.physics import EngineFigures, cengine, resolve_engine
from jaxenvs.testing import check_engine_parity

BUILTIN = [
    "CartPole-v0",
    "CartpoleStayUp-v0",
    "CartpoleBalance-v0",
    "CartpoleSwingup-v0",
    "Reacher-v0",
    "HexapodWalk-v0",
    "HexapodOneLeg-v0",
]
DEFAULT_PARITY = ("CartpoleStayUp-v0", "Reacher-v0")


def test_every_registered_task_is_checked_here():
    assert set(BUILTIN) <= set(jaxenvs.list_envs())


@pytest.mark.parametrize(
    "env_id",
    [
        # the default tier compares one task of each robot and StayUp (its servo runs a
        # callback per substep); the walker's MJX step compiles for ~11 s on 2 cores, and
        # CartPole-v0 and the swing-up read what the balance task reads: the full tier
        e if e in DEFAULT_PARITY else pytest.param(e, marks=pytest.mark.full)
        for e in BUILTIN
    ],
)
def test_engine_parity(env_id):
    """Obs, reward, termination and metrics agree between MJX and C step by step.

    The walker starts 0.3 m up and is compared over its first two control steps, before
    its feet reach the floor: in contact, MJX's and MuJoCo's solvers part from the first
    touch (their agreement on the ground is checked with test_hexapod's tolerances by
    test_walker_contact_parity below). The other tasks: 30 control steps.
    """
    if env_id == "HexapodWalk-v0":
        check_engine_parity(env_id, steps=2, init_height=0.3)
    else:
        check_engine_parity(env_id, steps=30)


class _Crossing:
    """A task measured faster under MJX from 256 envs per CPU device (no built-in task
    has such a cross-over today: every one runs on C at every size on a CPU)."""

    engine_figures = EngineFigures(cpu_physics="c", cpu_mjx_from=256)


def test_engine_rule_by_backend_and_batch_size():
    """``physics="auto"``: MJX on an accelerator; on a CPU the task's ``cpu_physics``, and
    MJX from its measured cross-over of ``cpu_mjx_from`` envs per CPU device on; ``"c"``
    only on a CPU."""
    from jaxenvs.tasks.cartpole import CartPole
    from jaxenvs.tasks.hexapod import HexapodWalk
    from jaxenvs.tasks.reacher import Reacher

    class Unmeasured:  # neither attribute: MJX everywhere
        pass

    cross = _Crossing.engine_figures.cpu_mjx_from * jax.local_device_count("cpu")
    assert resolve_engine(_Crossing, "auto", backend="cpu") == "c"
    assert resolve_engine(_Crossing, "auto", cross - 1, backend="cpu") == "c"
    assert resolve_engine(_Crossing, "auto", cross, backend="cpu") == "mjx"
    for task in (CartPole, Reacher, HexapodWalk):  # C at every size
        assert resolve_engine(task, "auto", backend="cpu") == "c"
        assert resolve_engine(task, "auto", 1 << 20, backend="cpu") == "c"
    assert resolve_engine(CartPole, "auto", 1 << 20, backend="gpu") == "mjx"
    assert resolve_engine(CartPole, "auto", backend="gpu") == "mjx"
    assert resolve_engine(Unmeasured, "auto", 16, backend="cpu") == "mjx"
    assert resolve_engine(CartPole, "mjx", 16, backend="cpu") == "mjx"
    assert resolve_engine(CartPole, "c", 1 << 20, backend="cpu") == "c"
    with pytest.raises(ValueError, match="CPU.*physics='mjx'"):
        resolve_engine(CartPole, "c", backend="gpu")
    with pytest.raises(ValueError, match="physics must be one of"):
        resolve_engine(CartPole, "warp")
    with pytest.raises(jaxenvs.ConfigError, match="physics"):
        jaxenvs.make("CartPole-v0", physics="C")


def test_engine_rule_counts_envs_per_cpu_device(monkeypatch):
    """The cross-over is per CPU device: with 8 host devices (a 16-core CPU) a task's
    batch goes to MJX from 8 x ``cpu_mjx_from`` envs, not from ``cpu_mjx_from``."""
    monkeypatch.setattr(jax, "local_device_count", lambda backend=None: 8)
    per_device = _Crossing.engine_figures.cpu_mjx_from
    assert resolve_engine(_Crossing, "auto", per_device, backend="cpu") == "c"
    assert resolve_engine(_Crossing, "auto", 8 * per_device - 1, backend="cpu") == "c"
    assert resolve_engine(_Crossing, "auto", 8 * per_device, backend="cpu") == "mjx"
    # another machine's count, given (a benchmark record's)
    assert resolve_engine(_Crossing, "auto", per_device, backend="cpu", cpu_devices=1) == "mjx"


def test_the_built_env_records_its_engine():
    env = jaxenvs.make("Reacher-v0")  # auto
    assert env.physics == env.config.physics == ("c" if jax.default_backend() == "cpu" else "mjx")
    assert jaxenvs.make("Reacher-v0", physics="mjx").config.physics == "mjx"


@pytest.mark.full
def test_every_provided_field_is_finite_after_a_walker_step(monkeypatch):
    from jaxenvs.tasks.hexapod import HexapodWalk

    monkeypatch.setattr(HexapodWalk, "derived_fields", None)  # every field
    env = jaxenvs.make("HexapodWalk-v0", physics="c")
    state = jax.jit(env.step)(jax.jit(env.reset)(jax.random.key(0)), jnp.zeros(18))
    data = state.data
    for name, in_impl in env.sim.engine.layout.outputs:
        value = np.asarray(getattr(data._impl if in_impl else data, name))
        assert np.all(np.isfinite(value)), name
    assert float(jnp.abs(data.actuator_force).max()) > 0  # the servos hold the stance
    assert float(jnp.abs(data.xpos[1]).max()) > 0  # the torso's pose, computed by C
    assert isinstance(data._impl.contact, cengine.Unavailable)


@pytest.mark.full
def test_nested_vmap_seeds_by_envs_matches_per_seed_runs():
    benv = jaxenvs.make("CartPole-v0", num_envs=3, physics="c")
    keys = jax.random.split(jax.random.key(0), 2)

    def roll(key):
        state = benv.reset(key)

        def body(s, k):
            s = benv.step(s, random_actions(benv.env, k, (3,)))
            return s, (s.obs, s.reward, s.done)

        return jax.lax.scan(body, state, jax.random.split(key, 40))[1]

    together = jax.jit(jax.vmap(roll))(keys)
    for i in range(2):
        alone = jax.jit(roll)(keys[i])
        for a, b in zip(together, alone, strict=True):
            np.testing.assert_array_equal(np.asarray(a[i]), np.asarray(b))
    assert np.asarray(together[2]).any()  # episodes ended and auto-reset inside the scan


def _trajectory(benv, key, steps=60):
    return jax.device_get(_roller(benv, steps)(key))


def _roller(benv, steps):
    """A jitted rollout of ``steps`` random actions from ``benv.reset(key)``."""

    def roll(key):
        def body(s, k):
            s = benv.step(s, random_actions(benv.env, k, (benv.num_envs,)))
            return s, (s.obs, s.data.qpos, s.done)

        return jax.lax.scan(body, benv.reset(key), jax.random.split(key, steps))[1]

    return jax.jit(roll)


@pytest.mark.full
def test_same_key_same_trajectory_whatever_the_thread_count(monkeypatch):
    monkeypatch.setattr(machine, "_cores", 2)
    two = jaxenvs.make("CartpoleBalance-v0", num_envs=32, physics="c", randomize=True)
    monkeypatch.setattr(machine, "_cores", 1)
    one = jaxenvs.make("CartpoleBalance-v0", num_envs=32, physics="c", randomize=True)
    assert (two.env.sim.engine.threads, one.env.sim.engine.threads) == (2, 1)
    monkeypatch.setattr(cengine, "SERIAL_WORK", 0)  # the 2-thread env really uses its pool
    roll_two = _roller(two, 60)  # one program, called twice
    a = jax.device_get(roll_two(jax.random.key(1)))
    b = jax.device_get(roll_two(jax.random.key(1)))
    c = _trajectory(one, jax.random.key(1))
    for x, y, z in zip(a, b, c, strict=True):
        np.testing.assert_array_equal(x, y)
        np.testing.assert_array_equal(x, z)


@pytest.mark.full  # compiles the MJX rollout too (~5 s on 2 cores): the full tier
def test_domain_randomisation_matches_mjx_env_by_env():
    """Per-env params reach the C model: C agrees with MJX env by env under DR."""
    c = jaxenvs.make("CartpoleBalance-v0", num_envs=8, randomize=True, physics="c")
    m = jaxenvs.make("CartpoleBalance-v0", num_envs=8, randomize=True, physics="mjx")
    oc, _, _ = _trajectory(c, jax.random.key(2), steps=40)
    om, _, _ = _trajectory(m, jax.random.key(2), steps=40)
    np.testing.assert_allclose(oc, om, atol=1e-4, rtol=1e-4)


@pytest.mark.full
def test_domain_randomisation_is_honoured():
    """Per-env params reach the C model: envs whose params differ move differently from
    the same start and actions (the full tier checks each against MJX env by env)."""
    env = jaxenvs.make("CartpoleBalance-v0", physics="c")
    state = env.reset(jax.random.key(3))
    p1, p2 = env.sample_params(jax.random.key(4)), env.sample_params(jax.random.key(5))
    params = jax.tree.map(lambda a, b: jnp.stack([a, b]), p1, p2)
    states = jax.tree.map(lambda x: jnp.stack([x, x]), state)
    step = jax.jit(jax.vmap(env.step))
    for _ in range(20):
        states = step(states, jnp.ones((2, 1)), params)
    qpos = np.asarray(states.data.qpos)
    assert np.abs(qpos[0] - qpos[1]).max() > 1e-3


def test_the_engine_writes_only_the_derived_fields_a_task_reads():
    """A task's ``derived_fields`` are written as by an engine that writes every field (bit
    for bit, the state too); the others are Unavailable and reading one names the
    attribute; an unknown name is refused."""
    env = jaxenvs.make("CartpoleBalance-v0", physics="c")
    assert env.derived_fields == () and env.sim.derived == ()
    base = jaxenvs.make("CartpoleBalance-v0", physics="mjx").sim
    full, some = base.with_physics("c"), base.with_physics("c", derived=("actuator_force",))
    data = env.reset(jax.random.key(0)).data
    assert isinstance(data.xpos, cengine.Unavailable)
    with pytest.raises(cengine.CEngineError, match="'xpos'.*derived_fields"):
        _ = data.xpos + 1.0
    ctrl = jnp.ones(1)
    a = jax.jit(full.step)(None, full._data0.replace(qpos=data.qpos, qvel=data.qvel), ctrl)
    b = jax.jit(some.step)(None, some._data0.replace(qpos=data.qpos, qvel=data.qvel), ctrl)
    c = jax.jit(env.sim.step)(None, data, ctrl)
    for name in ("qpos", "qvel", "qacc_warmstart", "time"):
        np.testing.assert_array_equal(getattr(a, name), getattr(b, name))
        np.testing.assert_array_equal(getattr(a, name), getattr(c, name))
    np.testing.assert_array_equal(a.actuator_force, b.actuator_force)
    assert float(jnp.abs(b.actuator_force).max()) > 0
    assert isinstance(b.xpos, cengine.Unavailable) and isinstance(
        c.actuator_force, cengine.Unavailable
    )
    n_full = len(jax.tree.leaves(a))
    assert len(jax.tree.leaves(b)) == len(jax.tree.leaves(c)) + 1 < n_full
    with pytest.raises(cengine.CEngineError, match="derived_fields: nope"):
        base.with_physics("c", derived=("nope",))
    with pytest.raises(TypeError, match="not the string 'xpos'"):
        base.with_physics("c", derived="xpos")  # type: ignore[arg-type]
    with pytest.raises(ValueError, match="from the MJX Sim"):
        some.with_physics("c")  # every field: not the world built for actuator_force


def test_unknown_params_field_is_refused_by_name():
    env = jaxenvs.make("CartpoleBalance-v0", physics="c")
    data = env.reset(jax.random.key(0)).data
    with pytest.raises(cengine.CEngineError, match="body_masss"):
        env.sim.step({"body_masss": jnp.ones(3)}, data, jnp.zeros(1))
    with pytest.raises(cengine.CEngineError, match="body_mass.*shape"):
        env.sim.step({"body_mass": jnp.ones(7)}, data, jnp.zeros(1))
    with pytest.raises(TypeError, match="model_with"):
        env.sim.step(jaxenvs.make("CartpoleBalance-v0", physics="mjx").sim.mx, data, jnp.zeros(1))


@pytest.mark.full  # two walker compiles (~30 s on 2 cores); the full tier runs it
def test_walker_contact_parity():
    """The walker on its feet: C and MJX within test_hexapod's MJX-vs-MuJoCo tolerances,
    both on Newton's solve (MJX's on a GPU; on a CPU its ``solver: auto`` is a few CG
    iterations, which stop short of the elliptic cone's solution)."""
    from tests.tasks.test_hexapod import WALK_HEIGHT_ATOL, WALK_JOINT_ATOL, WALK_XY_ATOL

    t = np.arange(60)[:, None] * 0.05
    actions = jnp.asarray(0.2 * np.sin(np.pi * t + 0.7 * np.arange(18)[None, :]), jnp.float32)
    qpos = {}
    for physics in ("mjx", "c"):
        env = jaxenvs.make("HexapodWalk-v0", physics=physics, solver="newton")

        def roll(key, env=env):
            def body(s, a):
                s = env.step(s, a)
                return s, s.data.qpos

            return jax.lax.scan(body, env.reset(key), actions)[1]

        qpos[physics] = np.asarray(jax.jit(roll)(jax.random.key(3)))
    err = np.abs(qpos["mjx"] - qpos["c"])
    assert err[:, 2].max() < WALK_HEIGHT_ATOL
    assert err[:, :2].max() < WALK_XY_ATOL
    assert err[:, 7:].max() < WALK_JOINT_ATOL


def test_config_records_resolved_engine():
    env = jaxenvs.make("CartPole-v0", physics="auto")
    assert dataclasses.asdict(env.config)["physics"] in ("mjx", "c")


def test_every_maker_applies_the_engine_rule():
    """``make``, a directly built env and a training run's config all resolve ``"auto"``
    through :func:`resolve_engine`, with their batch size."""
    from jaxenvs.run import run_config
    from jaxenvs.tasks.cartpole import CartPole

    on_cpu = jax.default_backend() == "cpu"
    for num_envs in (16, 4096):
        want = resolve_engine(CartPole, "auto", num_envs)
        assert want == ("c" if on_cpu else "mjx")
        assert jaxenvs.make("CartPole-v0", num_envs=num_envs).env.physics == want
        resolved = run_config.resolve_config(
            "CartPole-v0", "ppo", agent_overrides={"num_envs": num_envs}
        )
        assert run_config.engine_resolved(resolved).env.physics == want
    assert jaxenvs.make("CartPole-v0").physics == resolve_engine(CartPole, "auto")
    assert CartPole().physics == resolve_engine(CartPole, "auto")
    if on_cpu:
        assert jaxenvs.make("CartPole-v0", num_envs=4096, physics="c").env.physics == "c"


def test_an_unavailable_field_copies_and_pickles():
    """A C state's stand-in for a field the engine does not write survives copy and pickle
    (a Gymnasium env holding a C state deep-copies)."""
    import copy
    import pickle

    u = cengine.Unavailable("xpos", "derived")
    for v in (copy.deepcopy(u), pickle.loads(pickle.dumps(u))):
        assert isinstance(v, cengine.Unavailable) and (v.name, v.why) == ("xpos", "derived")
