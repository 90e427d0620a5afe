"""The C engine's native call and its callback fallback (:mod:`jaxenvs.physics.cengine`).

What these check: the install built and loaded the native engine (or, with
``JAXENVS_NATIVE=0``, that the callback path runs and says so in one line); both paths give
the same outputs bit for bit; every derived field a task may read matches MJX after a C
step, and a user's task that observes body and site poses and ``qacc`` passes the engine
parity check; applied forces are honoured; a bad state is caught on an episode's first
step; the contact arrays refuse to be read; a compiled program goes into JAX's persistent
cache and a second process loads it; a program that meets a model this process does not
hold fails with a clear error.
"""

from __future__ import annotations

import os
import subprocess
import sys
import textwrap

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
import pytest

import jaxenvs
from jaxenvs.actions import random_actions
from jaxenvs.physics import cengine, native
from jaxenvs.tasks.cartpole import BalanceConfig, CartpoleBalance
from jaxenvs.testing import check_engine_parity

NATIVE_OFF = os.environ.get(native.ENV_VAR, "1") == "0"


@pytest.fixture
def every_field(monkeypatch):
    """The shipped tasks' C engines write every derived field (``derived_fields = None``),
    for the checks of every field against MJX and across paths."""
    from jaxenvs.tasks import cartpole, hexapod, reacher

    for cls in (
        cartpole._CartpoleTask,
        reacher.Reacher,
        hexapod.HexapodWalk,
        hexapod.HexapodOneLeg,
        hexapod.HexapodJoystick,
    ):
        monkeypatch.setattr(cls, "derived_fields", None)


def test_the_install_built_the_native_engine():
    """CI installs from a clean clone: the native engine must be there and load (unless
    this run turns it off on purpose, when the callback path must be the one used)."""
    env = jaxenvs.make("Reacher-v0", physics="c")
    if NATIVE_OFF:
        assert env.sim.engine.path == "callback"
        assert native.ENV_VAR in (native.unavailable_reason() or "")
    else:
        assert native.available(), native.unavailable_reason()
        assert env.sim.engine.path == "native"


def _engines(env_id: str, **overrides):
    """The C env of ``env_id`` and a callback-path engine over the same host model (its
    blank data from the MJX build)."""
    env = jaxenvs.make(env_id, physics="c", **overrides)
    base = jaxenvs.make(env_id, physics="mjx", **overrides).sim
    other = cengine.CEngine(
        env.sim.physics_mj_model,
        base._data0,
        env.sim.engine.threads,
        "callback",
        derived=env.derived_fields,
    )
    return env, other


@pytest.mark.full
@pytest.mark.parametrize(
    "env_id",
    # the rough joystick: both paths collide the feet with the heightfield by jaxenvs'
    # collider (installed in the library both call, native/hfield.cc)
    ["CartpoleBalance-v0", "HexapodWalk-v0", "HexapodJoystickRough-v0"],
)
@pytest.mark.parametrize("fields", ["every", "the task's"])
def test_callback_path_matches_native_bit_for_bit(env_id, fields, request):
    if fields == "every":
        request.getfixturevalue("every_field")
    env, callback = _engines(env_id)
    if env.sim.engine.path != "native":
        pytest.fail(f"the native engine is not loaded: {native.unavailable_reason()}")
    benv = jaxenvs.make(env_id, physics="c", num_envs=6, randomize=True)
    state = jax.jit(benv.reset)(jax.random.key(0))
    actions = random_actions(benv.env, jax.random.key(1), (6,))
    params = state.params.model
    ctrl = jnp.clip(actions, -1, 1).reshape(6, -1)[:, : env.sim.mj_model.nu]
    outs = []
    for engine in (env.sim.engine, callback):
        f = jax.jit(jax.vmap(lambda p, d, c, engine=engine: engine.step(p, d, c, 3)))
        outs.append(jax.device_get(f(params, state.data, ctrl)))
    for (path, a), b in zip(
        jax.tree_util.tree_flatten_with_path(outs[0])[0], jax.tree.leaves(outs[1]), strict=True
    ):
        np.testing.assert_array_equal(a, b, err_msg=jax.tree_util.keystr(path))


def _one_step_both(env_id: str, steps: int = 2, **overrides):
    """The state after ``steps`` zero-action control steps under each engine, from the
    same reset (the walker's MJX compile is the long one)."""
    out = {}
    for physics in ("mjx", "c"):
        env = jaxenvs.make(env_id, physics=physics, **overrides)
        action = jnp.zeros(env.action_shape, jnp.int32 if env.discrete else jnp.float32)

        def roll(key, env=env, action=action):
            s = env.reset(key)
            for _ in range(steps):
                s = env.step(s, action)
            return s.data

        out[physics] = jax.device_get(jax.jit(roll)(jax.random.key(7)))
    return out, env


@pytest.mark.parametrize(
    "env_id",
    [
        # the full tier (an MJX compile each): the default tier compares C and MJX
        # trajectories (tests/test_cengine.py's parity) rather than every field
        pytest.param(e, marks=pytest.mark.full)
        for e in ("CartpoleStayUp-v0", "CartpoleBalance-v0", "Reacher-v0", "HexapodOneLeg-v0")
    ],
)
def test_every_provided_field_matches_mjx(env_id, every_field):
    """Every field the C engine writes (poses, com quantities, qacc, actuator
    quantities, the mass matrix, ...) holds what MJX computes for the same step."""
    out, env = _one_step_both(env_id)
    lay = env.sim.engine.layout
    checked = []
    for name, in_impl in lay.outputs:
        got = getattr(out["c"]._impl if in_impl else out["c"], name)
        want = getattr(out["mjx"]._impl if in_impl else out["mjx"], name)
        scale = max(1.0, float(np.max(np.abs(want), initial=0)))
        np.testing.assert_allclose(got, want, atol=2e-5 * scale, rtol=1e-4, err_msg=name)
        checked.append(name)
    for name in ("xpos", "xquat", "site_xpos", "qacc", "actuator_force", "cinert", "M"):
        assert name in checked


@pytest.mark.full  # the walker's MJX compile (~11 s on 2 cores)
def test_walker_fields_match_mjx_in_the_air(every_field):
    out, env = _one_step_both("HexapodWalk-v0", steps=1, init_height=0.3)
    for name, in_impl in env.sim.engine.layout.outputs:
        got = getattr(out["c"]._impl if in_impl else out["c"], name)
        want = getattr(out["mjx"]._impl if in_impl else out["mjx"], name)
        scale = max(1.0, float(np.max(np.abs(want), initial=0)))
        np.testing.assert_allclose(got, want, atol=1e-4 * scale, rtol=1e-3, err_msg=name)


class _ReadsPoses(CartpoleBalance):
    """A user's task whose observation reads a body position, a site position and qacc
    (which it declares: the C engine writes them)."""

    derived_fields = ("xpos", "site_xpos", "qacc")

    def _observe(self, key, data, extras, params):  # type: ignore[no-untyped-def]
        base = super()._observe(key, data, extras, params)
        return jnp.concatenate([base, data.xpos[2], data.site_xpos[0], data.qacc])

    @property
    def observation_size(self) -> int:  # type: ignore[override]
        return 5 + 3 + 3 + 2


@pytest.mark.full
def test_a_users_task_reading_poses_and_qacc_agrees_across_engines():
    jaxenvs.register("ReadsPoses-v0", _ReadsPoses, BalanceConfig(), "test task", overwrite=True)
    env = jaxenvs.make("ReadsPoses-v0", physics="c")
    state = jax.jit(env.step)(env.reset(jax.random.key(0)), jnp.zeros(1))
    assert not bool(state.info["diverged"])
    assert np.all(np.isfinite(np.asarray(state.obs)))
    check_engine_parity("ReadsPoses-v0", steps=20, atol=1e-3)


@pytest.mark.parametrize(
    "field", ["qfrc_applied", pytest.param("xfrc_applied", marks=pytest.mark.full)]
)
def test_applied_forces_are_honoured(field):
    """A 50 N push on the cart moves it as far under C as under MJX."""
    moved = {}
    for physics in ("mjx", "c"):
        env = jaxenvs.make("CartpoleBalance-v0", physics=physics)
        sim = env.sim
        cart = sim.mj_model.body("cart").id

        def roll(key, env=env, sim=sim, cart=cart):
            data = env.reset(key).data
            if field == "qfrc_applied":
                push = data.qfrc_applied.at[0].set(50.0)
            else:
                push = data.xfrc_applied.at[cart, 0].set(50.0)
            data = data.replace(**{field: push})
            model = sim.model_with(env.default_params.model)
            data = jax.lax.fori_loop(0, 25, lambda _, d: sim.step(model, d, jnp.zeros(1)), data)
            return data.qpos[0] - env.reset(key).data.qpos[0]

        moved[physics] = float(jax.jit(roll)(jax.random.key(0)))
    assert moved["mjx"] > 0.1
    assert moved["c"] == pytest.approx(moved["mjx"], rel=1e-2)


@pytest.mark.full
def test_a_bad_state_is_caught_on_an_episodes_first_step():
    """MuJoCo resets a state with an infinite velocity and carries on, its clock back at 0:
    at time 0 nothing but its warning shows it. The env is flagged diverged and
    terminated on that first step, and its batch neighbours are untouched."""
    benv = jaxenvs.make("CartpoleBalance-v0", physics="c", num_envs=3)
    state = benv.reset(jax.random.key(0))
    data = state.data.replace(qvel=state.data.qvel.at[1, 0].set(jnp.inf))
    nxt = jax.jit(benv.step)(state.replace(data=data), jnp.zeros((3, 1)))
    assert np.asarray(nxt.info["diverged"]).tolist() == [False, True, False]
    assert np.asarray(nxt.terminated).tolist() == [False, True, False]
    assert np.all(np.isfinite(np.asarray(nxt.obs)))  # the diverged env came back reset


def test_an_error_in_one_envs_step_spares_the_rest_of_the_batch():
    """MuJoCo raises an error (its stack overflows: too little arena memory for the
    contacts) in the steps of four envs resting on the floor. Those come back NaN with
    their clock advanced; every other env, those stepped after a failed one in the same
    thread included, is stepped bit for bit as in a batch without the failing ones."""
    from mujoco import mjx

    xml = """<mujoco><size memory="8K"/><worldbody><geom type="plane" size="5 5 .1"/>
      <body pos="0 0 2"><freejoint/><geom type="box" size=".1 .1 .1"/></body>
      <body pos="0 0 3"><freejoint/><geom type="box" size=".1 .1 .1"/></body>
      </worldbody></mujoco>"""
    model = mujoco.MjModel.from_xml_string(xml)
    template = mjx.make_data(model)
    engine = cengine.CEngine(model, template, threads=2)
    n, bad = 64, [1, 17, 18, 40]
    data = jax.tree.map(lambda leaf: jnp.broadcast_to(leaf, (n, *jnp.shape(leaf))), template)
    qpos = np.asarray(data.qpos).copy()
    qpos[:, 2] += np.linspace(0.0, 0.5, n)  # every env its own height in the air
    clean = data.replace(qpos=jnp.asarray(qpos))
    qpos[bad, 2] = 0.05  # these on the floor
    step = jax.jit(jax.vmap(lambda d: engine.step({}, d, jnp.zeros(0), 1)))
    out, ref = step(data.replace(qpos=jnp.asarray(qpos))), step(clean)
    failed = np.isnan(np.asarray(out.qpos)).any(axis=1)
    assert np.flatnonzero(failed).tolist() == bad
    np.testing.assert_array_equal(np.asarray(out.time), np.full(n, model.opt.timestep, np.float32))
    good = ~failed
    for name in ("qpos", "qvel", "qacc_warmstart"):
        np.testing.assert_array_equal(
            np.asarray(getattr(out, name))[good], np.asarray(getattr(ref, name))[good]
        )


@pytest.mark.full
def test_contact_arrays_refuse_to_be_read_naming_the_field():
    env = jaxenvs.make("HexapodWalk-v0", physics="c")
    data = env.reset(jax.random.key(0)).data
    with pytest.raises(cengine.CEngineError, match="'contact'.*physics='mjx'"):
        jax.jit(lambda d: d._impl.contact.dist)(data)
    with pytest.raises(cengine.CEngineError, match="'efc_force'"):
        jax.jit(lambda d: jnp.sum(d._impl.efc_force))(data)


@pytest.mark.full
def test_forward_fills_derived_fields_like_mjx(every_field):
    c = jaxenvs.make("Reacher-v0", physics="c")
    m = jaxenvs.make("Reacher-v0", physics="mjx")
    data = c.reset(jax.random.key(0)).data
    fc = jax.jit(lambda d: c.sim.forward(c.sim.model_with(c.default_params.model), d))(data)
    fm = jax.jit(lambda d: m.sim.forward(m.sim.model_with(m.default_params.model), d))(
        m.reset(jax.random.key(0)).data
    )
    np.testing.assert_allclose(fc.xpos, fm.xpos, atol=1e-6)
    np.testing.assert_array_equal(fc.qpos, data.qpos)


def test_a_program_for_an_unregistered_model_is_a_clear_error():
    env = jaxenvs.make("CartpoleBalance-v0", physics="c")
    if env.sim.engine.path != "native":
        pytest.fail(f"the native engine is not loaded: {native.unavailable_reason()}")
    engine = env.sim.engine
    data = env.reset(jax.random.key(0)).data
    real = engine.key
    try:
        engine.key = "mjb-0000"
        with pytest.raises(Exception, match="no MuJoCo model mjb-0000 is registered"):
            jax.block_until_ready(jax.jit(lambda d: engine.step({}, d, jnp.zeros(1), 1))(data))
    finally:
        engine.key = real


_CACHED_RUN = textwrap.dedent(
    """
    import jax, jax.numpy as jnp
    jax.config.update("jax_compilation_cache_dir", {cache!r})
    jax.config.update("jax_persistent_cache_min_compile_time_secs", 0)
    jax.config.update("jax_persistent_cache_min_entry_size_bytes", 0)
    hits = []
    jax.monitoring.register_event_listener(
        lambda name, **kw: hits.append(name) if name.endswith("cache_hits") else None)
    import jaxenvs
    env = jaxenvs.make("CartpoleBalance-v0", physics="c", num_envs=4)
    def roll(key):
        s = env.reset(key)
        s, _ = jax.lax.scan(lambda s, _: (env.step(s, jnp.ones((4, 1))), None), s, None, 50)
        return s.obs
    obs = jax.jit(roll)(jax.random.key(0))
    print("HITS", len(hits), "PATH", env.env.sim.engine.path, "OBS", float(obs.sum()))
    """
)


@pytest.mark.full
def test_a_program_compiled_in_one_process_loads_in_another(tmp_path):
    """Nothing process-specific is baked into a program that steps the native engine:
    the second process loads the first one's compiled rollout from the persistent cache
    and computes the same result."""
    script = tmp_path / "run.py"
    script.write_text(_CACHED_RUN.format(cache=str(tmp_path / "cache")))
    outs = []
    for _ in range(2):
        done = subprocess.run(
            [sys.executable, str(script)], capture_output=True, text=True, timeout=300
        )
        assert done.returncode == 0, done.stderr[-2000:]
        line = [x for x in done.stdout.splitlines() if x.startswith("HITS")][-1].split()
        outs.append(line)
    first, second = outs
    assert first[3] == second[3] == ("callback" if NATIVE_OFF else "native")
    assert first[5] == second[5]  # the same observations
    if not NATIVE_OFF:
        assert int(second[1]) > int(first[1])  # the rollout came from the cache


@pytest.mark.full
def test_native_off_runs_the_callback_and_says_so_in_one_line(tmp_path):
    code = (
        "import jax, jax.numpy as jnp, jaxenvs\n"
        "env = jaxenvs.make('CartpoleBalance-v0', physics='c')\n"
        "s = jax.jit(env.step)(env.reset(jax.random.key(0)), jnp.zeros(1))\n"
        "print('PATH', env.sim.engine.path, float(s.obs.sum()))\n"
    )
    env = {**os.environ, native.ENV_VAR: "0"}
    done = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, env=env, timeout=300
    )
    assert done.returncode == 0, done.stderr[-2000:]
    assert "PATH callback" in done.stdout
    warning = [x for x in done.stderr.splitlines() if "Python callback" in x]
    assert len(warning) == 1 and "JAXENVS_NATIVE=0" in warning[0]


_SPREAD_RUN = """
import jax, jax.numpy as jnp, numpy as np, jaxenvs
outs = []
for devices in (2, 1):
    b = jaxenvs.make("CartpoleBalance-v0", num_envs=8, physics="c", devices=devices,
                     randomize=True)
    def roll(key, b=b):
        def body(s, k):
            s = b.step(s, jax.random.uniform(k, (8, 1), minval=-1, maxval=1))
            return s, (s.obs, s.reward, s.done, s.data.qpos, s.data.qvel)
        return jax.lax.scan(body, b.reset(key), jax.random.split(key, 40))[1]
    outs.append(jax.device_get(jax.jit(roll)(jax.random.key(0))))
    print("DEVICES", b.devices)
same = all(np.array_equal(x, y) for x, y in zip(outs[0], outs[1]))
print("SAME", same)
"""


@pytest.mark.full
def test_a_c_batch_spread_over_two_devices_steps_as_on_one():
    """A C batch asked onto two host devices (the engine's calls from both run at once)
    gives the one-device trajectory, bit for bit."""
    env = {**os.environ, "XLA_FLAGS": "--xla_force_host_platform_device_count=2"}
    done = subprocess.run(
        [sys.executable, "-c", _SPREAD_RUN], capture_output=True, text=True, env=env, timeout=300
    )
    assert done.returncode == 0, done.stderr[-2000:]
    assert "DEVICES 2" in done.stdout and "DEVICES 1" in done.stdout
    assert "SAME True" in done.stdout


@pytest.mark.full
def test_native_calls_turn_off_only_the_bindings_default_clock():
    """MuJoCo's Python bindings time every step's stages with a default clock (a quarter of
    a small model's step); native calls turn that clock off, and keep one a user set."""
    import itertools

    import mujoco

    benv = jaxenvs.make("Reacher-v0", physics="c", num_envs=2)
    step = jax.jit(benv.step)
    state = jax.jit(benv.reset)(jax.random.key(0))
    actions = jnp.zeros((2, 2))
    model = benv.env.sim.physics_mj_model

    def timed() -> float:  # MuJoCo's step timer after one mj_step of a fresh MjData
        data = mujoco.MjData(model)
        mujoco.mj_step(model, data)
        return float(data.timer[int(mujoco.mjtTimer.mjTIMER_STEP)].duration)

    try:
        mujoco.set_mjcb_time(None)  # the bindings' default clock
        assert timed() > 0
        jax.block_until_ready(step(state, actions))
        assert (timed() == 0) != NATIVE_OFF  # native: off; callback path: untouched
        ticks = itertools.count()

        def clock() -> float:
            return float(next(ticks))

        mujoco.set_mjcb_time(clock)
        if NATIVE_OFF:  # mujoco.batch refuses a Python clock, naming it
            with pytest.raises(Exception, match="mjcb_time"):
                jax.block_until_ready(step(state, actions))
        else:
            jax.block_until_ready(step(state, actions))
        assert mujoco.get_mjcb_time() is clock and timed() > 0
    finally:
        mujoco.set_mjcb_time(None)
