"""Hexapod tasks: standing, falling, reachability, and parity with MuJoCo C.

Each env's ``step`` is jitted once per module and reused by every test. The task checks
run on the engine ``jaxenvs.make`` picks here (the C engine on a CPU); the parity checks
(actions mapped to servo targets by hand, stepped by ``mujoco.mj_step``) run on it, and
on MJX in the full tier (an MJX compile each; the walker's is about 15 s).
"""

from __future__ import annotations

from typing import Any

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
import pytest

from jaxenvs.config import ConfigError
from jaxenvs.robots.base import world_to_body
from jaxenvs.robots.hexapod import JOINT_RANGE, leg_tip, quat_to_mat
from jaxenvs.tasks.hexapod import (
    OBS_NOISE,
    HexapodOneLeg,
    HexapodWalk,
    OneLegConfig,
    WalkConfig,
    contact_solver,
)

# Parity tolerances (MJX float32 vs MuJoCo C float64, 100 control steps = 500 physics steps).
# The leg has no contacts: the two agree to float32 rounding. The walker's contacts are
# solved by 6 CG iterations, unconverged by design (speed), and MJX's CG line search is
# not MuJoCo C's, so contact forces differ from the first step on (2 mm of torso motion
# after one control step); feet that slip integrate that difference over the 5 s. The
# height must agree closely (both stand on the same floor); the horizontal drift and the
# joint angles within what a shuffling gait's slip gives (measured: benchmarks/NOTES.md).
LEG_QPOS_ATOL = 1e-4
WALK_HEIGHT_ATOL = 0.005  # m, torso height
WALK_XY_ATOL = 0.06  # m, torso horizontal position after up to 5 s of shuffling
WALK_JOINT_ATOL = 0.1  # rad, joint angles


_JITTED: dict[tuple[type, str, tuple], tuple] = {}


def _jitted(task: type, physics: str = "auto", **fields: Any) -> tuple:
    """(env, jitted reset, jitted step) of ``task`` on ``physics`` with config ``fields``,
    once per module."""
    key = (task, physics, tuple(sorted(fields.items())))
    if key not in _JITTED:
        make = {HexapodWalk: WalkConfig, HexapodOneLeg: OneLegConfig}[task]
        env = task(make(physics=physics, **fields))
        _JITTED[key] = env, jax.jit(env.reset), jax.jit(env.step)
    return _JITTED[key]


@pytest.fixture(scope="module")
def walk():
    return _jitted(HexapodWalk)


@pytest.fixture(scope="module")
def leg():
    return _jitted(HexapodOneLeg)


def _mj_rollout(env, qpos, mocap, ctrls):
    """Step MuJoCo C from ``qpos`` holding each ctrl for ``env.sim.substeps`` steps."""
    m = env.sim.mj_model
    d = mujoco.MjData(m)
    d.qpos[:] = qpos
    d.mocap_pos[:] = mocap
    out = []
    for ctrl in ctrls:
        d.ctrl[:] = ctrl
        for _ in range(env.sim.substeps):
            mujoco.mj_step(m, d)
        out.append(d.qpos.copy())
    return np.array(out)


def _noiseless(env, state):
    """The walker's observation of ``state`` without noise: its readings and target."""
    return env.observation(env.robot.sense(state.data), env.task_state(state.data, state.extras))


def test_quat_to_mat_matches_mujoco():
    q = np.array([0.3, -0.5, 0.7, 0.4])
    q /= np.linalg.norm(q)
    expected = np.zeros(9)
    mujoco.mju_quat2Mat(expected, q)
    np.testing.assert_allclose(quat_to_mat(jnp.asarray(q)), expected.reshape(3, 3), atol=1e-6)


@pytest.mark.full
def test_walker_stands_for_two_seconds(walk):
    env, reset, step = walk
    state = reset(jax.random.key(0))
    for _ in range(40):  # 40 x 0.05 s
        state = step(state, jnp.zeros(18))
        assert not bool(state.terminated)
    assert 0.12 < float(state.data.qpos[2]) < 0.14
    assert float(jnp.abs(state.data.qvel).max()) < 0.05  # settled, not jittering
    up = quat_to_mat(state.data.qpos[3:7])[2, 2]
    assert float(up) > 0.99


def test_walker_pushed_over_terminates(walk):
    env, reset, step = walk
    state = reset(jax.random.key(1))
    flipped = state.data.qpos.at[3:7].set(jnp.array([0.0, 1.0, 0.0, 0.0]))  # 180 deg about x
    state = state.replace(data=state.data.replace(qpos=flipped.at[2].set(0.3)))
    state = step(state, jnp.zeros(18))
    assert bool(state.terminated)
    assert float(state.obs[39]) > 0.9  # gravity points up in the body frame


def test_walker_observation_and_reward_terms(walk):
    env, reset, step = walk
    state = reset(jax.random.key(2))
    target = np.asarray(state.data.mocap_pos[0, :2])
    assert 1.0 <= np.linalg.norm(target) <= 3.0
    direction = np.asarray(state.obs[46:49])
    assert abs(np.linalg.norm(direction) - 1.0) < 1e-5
    state2 = step(state, jnp.zeros(18))
    d0 = np.linalg.norm(target - np.asarray(state.data.qpos[:2]))
    d1 = float(state2.info["distance"])
    assert abs(float(state2.info["progress"]) - (d0 - d1) / 0.05) < 1e-3


def test_walker_draws_a_new_target_on_arrival(walk):
    """Waypoints: a step that ends within ``waypoint_radius`` of the target draws a new one
    at a distance in ``target_range`` from the body, counts the arrival, and pays the
    progress toward the target it reached; a step that ends farther keeps its target."""
    env, reset, step = walk
    state = reset(jax.random.key(5))
    assert int(state.extras.targets_reached) == 0
    body = state.data.qpos[:2]
    near = state.data.mocap_pos.at[0, :2].set(body + jnp.array([0.1, 0.0]))
    state = state.replace(data=state.data.replace(mocap_pos=near))
    arrived = step(state, jnp.zeros(18))
    new = np.asarray(arrived.data.mocap_pos[0, :2])
    pos = np.asarray(arrived.data.qpos[:2])
    assert 1.0 <= np.linalg.norm(new - pos) <= 3.0  # the default target_range
    assert int(arrived.extras.targets_reached) == 1
    assert float(arrived.info["targets_reached"]) == 1.0
    old, start = np.asarray(near[0, :2]), np.asarray(body)
    np.testing.assert_allclose(float(arrived.info["distance"]), np.linalg.norm(old - pos), 1e-5)
    progress = (np.linalg.norm(old - start) - np.linalg.norm(old - pos)) / env.control_dt
    np.testing.assert_allclose(float(arrived.info["progress"]), progress, atol=1e-3)
    to_new = np.append((new - pos) / np.linalg.norm(new - pos), 0.0)
    expected = world_to_body(arrived.data.qpos[3:7], jnp.asarray(to_new, jnp.float32))
    np.testing.assert_allclose(np.asarray(arrived.obs[46:49]), expected, atol=1e-5)
    kept = step(arrived, jnp.zeros(18))
    np.testing.assert_array_equal(kept.data.mocap_pos, arrived.data.mocap_pos)
    assert int(kept.extras.targets_reached) == 1


@pytest.mark.full
def test_walker_waypoints_per_env_in_a_batch_and_off():
    """Vmapped, only the env that arrives draws a new target; ``waypoint_radius=0`` keeps
    one target per episode; a target range starting inside the radius is refused."""
    env, _, _ = _jitted(HexapodWalk)
    states = jax.vmap(env.reset)(jax.random.split(jax.random.key(6), 2))
    bodies = states.data.qpos[:, :2]
    near = states.data.mocap_pos.at[0, 0, :2].set(bodies[0] + jnp.array([0.0, 0.1]))
    states = states.replace(data=states.data.replace(mocap_pos=near))
    stepped = jax.jit(jax.vmap(env.step))(states, jnp.zeros((2, 18)))
    assert np.asarray(stepped.extras.targets_reached).tolist() == [1, 0]
    assert not np.array_equal(stepped.data.mocap_pos[0], near[0])
    np.testing.assert_array_equal(stepped.data.mocap_pos[1], near[1])
    single = HexapodWalk(WalkConfig(physics="c", waypoint_radius=0.0))
    s = single.reset(jax.random.key(5))
    s = s.replace(data=s.data.replace(mocap_pos=near[0]))
    out = jax.jit(single.step)(s, jnp.zeros(18))
    np.testing.assert_array_equal(out.data.mocap_pos, near[0])
    assert int(out.extras.targets_reached) == 0
    with pytest.raises(ConfigError, match="target_distance"):
        WalkConfig(target_distance=(0.2, 3.0)).validate()


@pytest.mark.full
def test_walker_noise_options_default_off_and_keyed():
    """action_noise / obs_noise: off by default (the noiseless observation), and drawn
    from the hooks' keys (same key, same noise; another key, other noise)."""
    quiet = HexapodWalk(WalkConfig(physics="c"))
    noisy = HexapodWalk(WalkConfig(physics="c", action_noise=0.1, obs_noise=1.0))
    key = jax.random.key(3)
    s0, n0 = quiet.reset(key), noisy.reset(key)
    np.testing.assert_array_equal(s0.obs, _noiseless(quiet, s0))
    assert np.allclose(n0.data.qpos, s0.data.qpos)  # noise does not touch the init
    sensed = np.asarray(_noiseless(noisy, n0))
    err = np.asarray(n0.obs) - sensed
    assert np.all(np.abs(err) < 6 * OBS_NOISE) and np.any(err != 0)
    np.testing.assert_array_equal(noisy.reset(key).obs, n0.obs)
    assert not np.array_equal(noisy.reset(jax.random.key(4)).obs[:18], n0.obs[:18])
    a = jnp.zeros(18)
    q_quiet = quiet.step(s0, a).data.qpos
    q_noisy = noisy.step(n0, a).data.qpos
    assert not np.allclose(q_noisy, q_quiet)  # the servo targets moved
    np.testing.assert_array_equal(noisy.step(n0, a).data.qpos, q_noisy)


def test_walker_tilt_and_spin_penalties(walk):
    """The robustness terms: ``-tilt_weight * (1 - up_z) - spin_weight * (w_x^2 + w_y^2)``
    on top of the default reward, for a body tilted 0.4 rad that rolls, pitches and yaws."""
    env, reset, step = walk
    state = reset(jax.random.key(4))
    prev = step(state, jnp.zeros(18)).data
    tilt = jnp.array([jnp.cos(0.2), jnp.sin(0.2), 0.0, 0.0])  # 0.4 rad about x
    qvel = prev.qvel.at[3:6].set(jnp.array([1.5, -0.5, 3.0]))
    nxt = prev.replace(qpos=prev.qpos.at[3:7].set(tilt), qvel=qvel)
    shaped = HexapodWalk(WalkConfig(tilt_weight=2.0, spin_weight=0.1))
    params, action, extras = env.default_params, jnp.zeros(18), state.extras
    base, _ = env._reward(state.data, nxt, action, extras, params)
    reward, _ = shaped._reward(state.data, nxt, action, extras, params)
    fallen = env._terminated(nxt, extras, params)
    shaped_fallen = shaped._terminated(nxt, extras, params)
    up_z = quat_to_mat(nxt.qpos[3:7])[2, 2]
    expected = base - 2.0 * (1.0 - up_z) - 0.1 * jnp.sum(nxt.qvel[3:5] ** 2)
    assert float(1.0 - up_z) > 0.05 and float(jnp.sum(nxt.qvel[3:5] ** 2)) > 0.5
    np.testing.assert_allclose(float(reward), float(expected), rtol=1e-5)
    assert bool(fallen) == bool(shaped_fallen)


@pytest.mark.parametrize(
    "physics",
    ["auto", pytest.param("mjx", marks=pytest.mark.full)],  # the walker's MJX compile
)
def test_walker_parity_with_mujoco(physics):
    """The walker stepped by ``physics`` and by MuJoCo C on the env's own host model agree
    over 100 control steps of a sine gait. MJX on a CPU runs Newton's solve here, as on a
    GPU: its default there, ``solver: auto``'s few CG iterations, stops short of the
    elliptic cone's solution, where C's Newton converges."""
    fields = {"solver": "newton"} if physics == "mjx" else {}
    env, reset, step = _jitted(HexapodWalk, physics, **fields)
    state = reset(jax.random.key(3))
    qpos0 = np.asarray(state.data.qpos, np.float64)
    mocap = np.asarray(state.data.mocap_pos, np.float64)
    t = np.arange(100)[:, None] * 0.05
    phase = np.arange(18)[None, :] * 0.7
    actions = (0.2 * np.sin(2 * np.pi * 0.5 * t + phase)).astype(np.float32)
    mjx_qpos = []
    for a in actions:
        state = step(state, jnp.asarray(a))
        mjx_qpos.append(np.asarray(state.data.qpos))
    mjx_qpos = np.array(mjx_qpos)
    ctrls = actions * np.asarray(JOINT_RANGE)
    c_qpos = _mj_rollout(env, qpos0, mocap, ctrls)
    err = np.abs(mjx_qpos - c_qpos)
    print(
        f"walker parity: xy {err[:, :2].max():.4f} z {err[:, 2].max():.4f} joints "
        f"{err[:, 7:].max():.4f}, first step xy {err[0, :2].max():.4f}"
    )
    assert err[:, 2].max() < WALK_HEIGHT_ATOL
    assert err[:, :2].max() < WALK_XY_ATOL
    assert err[:, 7:].max() < WALK_JOINT_ATOL


@pytest.mark.full
def test_one_leg_target_is_reachable(leg):
    env, reset, step = leg
    states = jax.vmap(env.reset)(jax.random.split(jax.random.key(4), 512))
    target_q = np.asarray(states.extras.target_q)
    assert np.all(np.abs(target_q) <= np.asarray(JOINT_RANGE[:3]) + 1e-6)
    targets = np.asarray(states.obs[:, 6:9])
    fk = np.asarray(jax.vmap(leg_tip)(states.extras.target_q))
    np.testing.assert_allclose(fk, targets, atol=1e-6)
    # forward kinematics agrees with MuJoCo's own kinematics of the leg model
    m = env.sim.mj_model
    d = mujoco.MjData(m)
    tip = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_SITE, "tip")
    hip = m.body_pos[mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, "base")]
    for q, target, mocap in zip(
        target_q[:20], targets[:20], np.asarray(states.data.mocap_pos)[:20], strict=True
    ):
        d.qpos[:] = q
        mujoco.mj_kinematics(m, d)
        np.testing.assert_allclose(d.site_xpos[tip], mocap[0], atol=1e-5)
        np.testing.assert_allclose(d.site_xpos[tip] - hip, target, atol=1e-5)
    # the workspace is really covered: targets spread over the leg's reach
    assert np.ptp(targets[:, 2]) > 0.2 and np.ptp(targets[:, 1]) > 0.1


@pytest.mark.full
def test_one_leg_servo_reaches_target(leg):
    env, reset, step = leg
    state = reset(jax.random.key(5))
    action = jnp.clip(state.extras.target_q / JOINT_RANGE[:3], -1.0, 1.0)
    for _ in range(40):
        state = step(state, action)
    assert float(state.info["distance"]) < 0.01  # 1 cm: the servo's sag under gravity
    assert float(state.reward) > -1e-4


@pytest.mark.parametrize("physics", ["auto", pytest.param("mjx", marks=pytest.mark.full)])
def test_one_leg_parity_with_mujoco(physics):
    env, reset, step = _jitted(HexapodOneLeg, physics)
    state = reset(jax.random.key(6))
    qpos0 = np.asarray(state.data.qpos, np.float64)
    mocap = np.asarray(state.data.mocap_pos, np.float64)
    actions = np.asarray(jax.random.uniform(jax.random.key(7), (100, 3), minval=-1, maxval=1))
    mjx_qpos = []
    for a in actions:
        state = step(state, jnp.asarray(a))
        mjx_qpos.append(np.asarray(state.data.qpos))
    c_qpos = _mj_rollout(env, qpos0, mocap, actions * np.asarray(JOINT_RANGE[:3]))
    np.testing.assert_allclose(np.array(mjx_qpos), c_qpos, atol=LEG_QPOS_ATOL)


@pytest.mark.parametrize(
    ("solver", "physics", "backend", "chosen"),
    [
        ("auto", "c", "cpu", "newton"),
        ("auto", "mjx", "gpu", "newton"),
        ("auto", "mjx", "cpu", "cg"),
        ("cg", "c", "cpu", "cg"),
        ("newton", "mjx", "cpu", "newton"),
    ],
)
def test_contact_solver_is_newton_but_for_mjx_on_a_cpu(solver, physics, backend, chosen) -> None:
    assert contact_solver(solver, physics, backend) == chosen


def test_a_flat_task_takes_the_family_contact_model():
    """The walker's default contact is the elliptic cone with ``solver: auto``: Newton
    under MuJoCo C (4 iterations, 20 line-search steps), CG for MJX on a CPU (its 6 / 3);
    its config can name the pyramidal cone and CG instead; a bad cone or solver is named."""
    for physics, solver, steps in (
        ("c", mujoco.mjtSolver.mjSOL_NEWTON, (4, 20)),
        ("mjx", mujoco.mjtSolver.mjSOL_CG, (6, 3)),
    ):
        sim = HexapodWalk(WalkConfig(physics=physics)).sim
        for model in (sim.mj_model, sim.physics_mj_model):
            opt = model.opt
            assert (opt.cone, opt.solver) == (mujoco.mjtCone.mjCONE_ELLIPTIC, solver)
            assert (opt.iterations, opt.ls_iterations) == steps
    pyramid = HexapodWalk(WalkConfig(physics="c", cone="pyramidal", solver="cg")).sim.mj_model
    assert (pyramid.opt.cone, pyramid.opt.solver) == (
        mujoco.mjtCone.mjCONE_PYRAMIDAL,
        mujoco.mjtSolver.mjSOL_CG,
    )
    assert (pyramid.opt.iterations, pyramid.opt.ls_iterations) == (6, 3)
    for field, value in (("cone", "round"), ("solver", "pgs")):
        with pytest.raises(ConfigError, match=field):
            WalkConfig(**{field: value}).validate()
