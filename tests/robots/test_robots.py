"""The robot layer: each robot's declaration (joints, actuators, sensors, command map),
its readings against MuJoCo's own sensors, its kinematics, its randomisation.

Everything here is host MuJoCo or small jitted JAX functions (no MJX physics compile);
the C engine's sensordata check builds the native engine only.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
import pytest
from mujoco import mjx

import jaxenvs
from jaxenvs.robots import robot_xml
from jaxenvs.robots.base import STATE_SENSORS, Robot, gravity_in_body, quat_to_mat
from jaxenvs.robots.cartpole import Cartpole, CartpoleRanges
from jaxenvs.robots.hexapod import (
    JOINT_RANGE,
    Hexapod,
    HexapodLeg,
    HexapodRanges,
    leg_tip,
    servo_targets,
)
from jaxenvs.robots.reacher import ReacherArm, ReacherRanges

ROBOTS = [Cartpole, ReacherArm, Hexapod, HexapodLeg]


def _random_state(model: mujoco.MjModel, rng: np.random.Generator) -> tuple[np.ndarray, ...]:
    """A random (qpos, qvel): joints in +-pi, free bodies anywhere with a unit quaternion."""
    qpos = rng.uniform(-np.pi, np.pi, model.nq)
    qvel = rng.normal(0.0, 2.0, model.nv)
    for j in range(model.njnt):
        if model.jnt_type[j] == mujoco.mjtJoint.mjJNT_FREE:
            a = model.jnt_qposadr[j]
            qpos[a : a + 3] = rng.normal(0.0, 1.0, 3)
            quat = rng.normal(0.0, 1.0, 4)
            qpos[a + 3 : a + 7] = quat / np.linalg.norm(quat)
    return qpos, qvel


@pytest.mark.parametrize("cls", ROBOTS)
def test_every_joint_has_an_encoder_and_privileged_sensors_exist(cls):
    robot = cls()
    scalar = [n for n, j in robot.joints.items() if j.kind in ("hinge", "slide")]
    assert len(robot.encoders) == len(scalar)
    assert {robot.sensors[n].joint for n in robot.encoders} == set(scalar)
    assert set(robot.privileged) <= set(robot.sensors)
    assert set(robot.observable()) == set(robot.sensors) - set(robot.privileged)
    assert len(robot.actuators) == robot.model.nu


@pytest.mark.parametrize("cls", ROBOTS)
def test_sense_equals_mujoco_sensors_after_forward(cls):
    """Every state sensor's reading is MuJoCo's sensordata after mj_forward at that state:
    the MJCF's declaration and the robot's evaluation agree."""
    robot = cls()
    m = robot.model
    d = mujoco.MjData(m)
    rng = np.random.default_rng(0)
    sense = jax.jit(robot.sense)
    blank = mjx.make_data(m)
    checked = set()
    for _ in range(20):
        d.qpos[:], d.qvel[:] = _random_state(m, rng)
        mujoco.mj_forward(m, d)
        data = blank.replace(
            qpos=jnp.asarray(d.qpos, jnp.float32),
            qvel=jnp.asarray(d.qvel, jnp.float32),
            sensordata=jnp.asarray(d.sensordata, jnp.float32),
        )
        readings = sense(data)
        for name, s in robot.sensors.items():
            if not s.from_state:
                assert name not in readings  # sensordata-backed: off by default
                continue
            want = d.sensordata[s.adr : s.adr + s.dim]
            np.testing.assert_allclose(readings[name], want, atol=2e-5, err_msg=name)
            checked.add(s.kind)
    assert checked == {s.kind for s in robot.sensors.values() if s.kind in STATE_SENSORS}


def test_sense_vmaps_over_a_batch():
    robot = Hexapod()
    rng = np.random.default_rng(1)
    states = [_random_state(robot.model, rng) for _ in range(4)]
    qpos = jnp.asarray(np.stack([s[0] for s in states]), jnp.float32)
    qvel = jnp.asarray(np.stack([s[1] for s in states]), jnp.float32)
    blank = mjx.make_data(robot.model)
    readings = jax.vmap(lambda q, v: robot.sense(blank.replace(qpos=q, qvel=v)))(qpos, qvel)
    assert readings["imu_quat"].shape == (4, 4) and readings["torso_vel"].shape == (4, 3)
    assert robot.joint_pos(readings).shape[-1] == 18


def test_hexapod_sensors_and_privilege():
    robot = Hexapod()
    kinds = {s.kind for s in robot.sensors.values()}
    assert {"jointpos", "jointvel", "framequat", "gyro", "accelerometer"} <= kinds
    assert robot.privileged == {"torso_vel", "torso_pos"}
    assert not robot.sensors["imu_accel"].from_state
    assert "imu_accel" in robot.observable() and "torso_vel" not in robot.observable()


def test_sensor_evaluation_flag_sets_mujoco_disable_bit():
    off = mujoco.mjtDisableBit.mjDSBL_SENSOR
    quiet = HexapodLeg().make_sim(0.01, 5)
    loud = HexapodLeg(sensordata=True).make_sim(0.01, 5)
    assert quiet.physics_mj_model.opt.disableflags & off
    assert not loud.physics_mj_model.opt.disableflags & off


def test_c_engine_fills_sensordata_one_substep_old():
    """With ``sensordata=True`` the C engine's step leaves MuJoCo's sensordata (the
    accelerometer's, from the last substep's forward pass) in the state; without, zeros."""
    robot = Hexapod(sensordata=True)
    sim = robot.make_sim(0.01, 5).with_physics("c")
    qpos = robot.qpos(jnp.array([0.0, 0.0, 0.14]), jnp.array([1.0, 0.0, 0.0, 0.0]), jnp.zeros(18))
    data = sim.init_data(qpos=qpos, qvel=jnp.zeros(24))
    ctrl = robot.command(jnp.full(18, 0.3))
    out = sim.step(sim.model_with({}), data, ctrl)
    m = sim.physics_mj_model
    d = mujoco.MjData(m)
    d.qpos[:] = np.asarray(qpos, np.float64)
    d.ctrl[:] = np.asarray(ctrl, np.float64)
    for _ in range(5):
        mujoco.mj_step(m, d)
    accel = robot.sensors["imu_accel"]
    want = d.sensordata[accel.adr : accel.adr + 3]
    np.testing.assert_allclose(robot.sense(out)["imu_accel"], want, rtol=1e-4, atol=1e-4)
    assert np.linalg.norm(want) > 1.0
    quiet = Hexapod()
    qsim = quiet.make_sim(0.01, 5).with_physics("c")
    qout = qsim.step(qsim.model_with({}), qsim.init_data(qpos=qpos, qvel=jnp.zeros(24)), ctrl)
    assert not np.any(np.asarray(qout.sensordata))
    np.testing.assert_array_equal(qout.qpos, out.qpos)  # sensors do not change the physics


def test_limits_are_the_mjcf_ones():
    hexapod, cartpole = Hexapod(), Cartpole()
    low, high = hexapod.force_range
    np.testing.assert_array_equal(high, np.full(18, 2.0))  # servo stall torque (N m)
    np.testing.assert_array_equal(low, np.full(18, -2.0))
    assert np.all(np.isinf(cartpole.force_range[1]))
    assert all(j.range is None for j in hexapod.joints.values())  # the servo range limits
    assert all(j.range is None for j in cartpole.joints.values())


def test_hexapod_command_map_spans_each_joint_range():
    for robot, n in ((Hexapod(), 18), (HexapodLeg(), 3)):
        low, high = robot.command_range
        np.testing.assert_array_equal(high, JOINT_RANGE[:n])
        np.testing.assert_array_equal(low, -JOINT_RANGE[:n])
        a = jnp.asarray(np.random.default_rng(2).uniform(-1, 1, n), jnp.float32)
        np.testing.assert_array_equal(robot.command(a), servo_targets(a))
        np.testing.assert_allclose(
            robot.model.actuator_ctrlrange, np.stack([low, high], 1), rtol=1e-6
        )


def test_leg_tip_matches_mujoco_site():
    robot = HexapodLeg()
    m = robot.model
    d = mujoco.MjData(m)
    tip = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_SITE, "tip")
    rng = np.random.default_rng(3)
    for _ in range(20):
        q = rng.uniform(-1, 1, 3) * JOINT_RANGE[:3]
        d.qpos[:] = q
        mujoco.mj_kinematics(m, d)
        np.testing.assert_allclose(
            robot.hip + leg_tip(jnp.asarray(q, jnp.float32)), d.site_xpos[tip], atol=1e-6
        )


def test_frame_helpers_match_mujoco():
    q = np.array([0.3, -0.5, 0.7, 0.4])
    q /= np.linalg.norm(q)
    mat = np.zeros(9)
    mujoco.mju_quat2Mat(mat, q)
    mat = mat.reshape(3, 3)
    np.testing.assert_allclose(quat_to_mat(jnp.asarray(q)), mat, atol=1e-6)
    np.testing.assert_allclose(gravity_in_body(jnp.asarray(q)), mat.T @ [0, 0, -1], atol=1e-6)


@pytest.mark.parametrize("cls", [Hexapod, HexapodLeg])
def test_hexapod_randomisation_stays_in_its_ranges(cls):
    robot = cls()
    # the walker on its floor (the scene holds the foot-floor pairs); the leg alone
    sim = robot.make_sim(0.01, 5, scene=robot.scene() if cls is Hexapod else None)
    base = robot.default_fields(sim)
    assert ("pair_friction" in base) == (cls is Hexapod)
    ranges = HexapodRanges(mass_scale=(0.5, 0.6), gain_scale=(2.0, 3.0), damping_scale=(1, 1))
    draws = jax.vmap(lambda k: robot.sample_fields(k, base, ranges))(
        jax.random.split(jax.random.key(0), 64)
    )
    moving = np.asarray(base["body_mass"]) > 0
    mass = np.asarray(draws["body_mass"])[:, moving] / np.asarray(base["body_mass"])[moving]
    assert mass.min() >= 0.5 - 1e-6 and mass.max() <= 0.6 + 1e-6
    kp = np.asarray(draws["actuator_gainprm"])[:, :, 0] / np.asarray(base["actuator_gainprm"])[:, 0]
    assert kp.min() >= 2.0 - 1e-6 and kp.max() <= 3.0 + 1e-6
    bias = (
        np.asarray(draws["actuator_biasprm"])[:, :, 1] / np.asarray(base["actuator_biasprm"])[:, 1]
    )
    np.testing.assert_allclose(bias, kp, rtol=1e-6)  # gain and bias scaled together
    np.testing.assert_array_equal(draws["dof_damping"][0], base["dof_damping"])
    if "pair_friction" in base:
        friction = np.asarray(draws["pair_friction"]) / np.asarray(base["pair_friction"])
        assert friction.min() >= 0.7 - 1e-6 and friction.max() <= 1.3 + 1e-6


def test_robot_xml_finds_each_shipped_mjcf_in_its_folder():
    assert robot_xml("hexapod_leg").parent.name == "hexapod"
    assert robot_xml("hexapod").is_file()
    with pytest.raises(ValueError, match="unknown robot 'biped'"):
        robot_xml("biped")


def test_a_sensor_the_robot_cannot_evaluate_is_refused(tmp_path):
    xml = (
        robot_xml("hexapod")
        .read_text()
        .replace('<gyro name="imu_gyro" site="imu"/>', '<gyro name="imu_gyro" site="lf_tip"/>')
    )
    path = tmp_path / "hexapod.xml"
    path.write_text(xml)

    class Moved(Robot):
        pass

    Moved.xml = path
    with pytest.raises(ValueError, match="'imu_gyro' must be on an unrotated site"):
        Moved()


@pytest.mark.parametrize("cls", [Cartpole, ReacherArm])
def test_motor_command_map_is_the_action(cls):
    robot = cls()
    low, high = robot.command_range
    np.testing.assert_array_equal(low, -np.ones(robot.model.nu))
    np.testing.assert_array_equal(high, np.ones(robot.model.nu))
    a = jnp.asarray(np.random.default_rng(4).uniform(-1, 1, robot.model.nu), jnp.float32)
    np.testing.assert_array_equal(robot.command(a), a)
    assert not robot.privileged


def test_cartpole_readings_name_its_state():
    robot = Cartpole()
    blank = mjx.make_data(robot.model)
    data = blank.replace(qpos=jnp.array([0.5, -0.2]), qvel=jnp.array([1.5, 3.0]))
    readings = robot.sense(data)
    np.testing.assert_array_equal(robot.state(readings), np.float32([0.5, 1.5, -0.2, 3.0]))


@pytest.mark.full
def test_cartpole_randomisation_stays_in_its_ranges():
    robot = Cartpole()
    base = robot.default_fields(robot.make_sim(0.01, 1))
    ranges = CartpoleRanges(mass_scale=(0.5, 0.6), damping_range=(0.1, 0.2), gain_scale=(2, 3))
    draws = jax.vmap(lambda k: robot.sample_fields(k, base, ranges))(
        jax.random.split(jax.random.key(1), 64)
    )
    moving = np.asarray(base["body_mass"]) > 0
    mass = np.asarray(draws["body_mass"])[:, moving] / np.asarray(base["body_mass"])[moving]
    assert mass.min() >= 0.5 - 1e-6 and mass.max() <= 0.6 + 1e-6
    damping = np.asarray(draws["dof_damping"]) - np.asarray(base["dof_damping"])
    assert damping.min() >= 0.1 - 1e-6 and damping.max() <= 0.2 + 1e-6
    gear = np.asarray(draws["actuator_gear"])[:, 0, 0] / float(base["actuator_gear"][0, 0])
    assert gear.min() >= 2 - 1e-5 and gear.max() <= 3 + 1e-5


def test_reacher_randomisation_scales_the_links_only():
    robot = ReacherArm()
    base = robot.default_fields(robot.make_sim(0.02, 1))
    ranges = ReacherRanges(mass_scale=(0.5, 0.6), armature_scale=(2, 3))
    draws = jax.vmap(lambda k: robot.sample_fields(k, base, ranges))(
        jax.random.split(jax.random.key(2), 64)
    )
    mass0 = np.asarray(base["body_mass"])
    ratio = np.asarray(draws["body_mass"]) / np.where(mass0 > 0, mass0, 1)
    links = [
        mujoco.mj_name2id(robot.model, mujoco.mjtObj.mjOBJ_BODY, b) for b in ("link0", "link1")
    ]
    others = [b for b in range(robot.model.nbody) if b not in links]
    assert ratio[:, links].min() >= 0.5 - 1e-6 and ratio[:, links].max() <= 0.6 + 1e-6
    np.testing.assert_array_equal(
        np.asarray(draws["body_mass"])[:, others],
        np.broadcast_to(mass0[others], (64, len(others))),
    )
    armature = np.asarray(draws["dof_armature"]) / np.asarray(base["dof_armature"])
    assert armature.min() >= 2 - 1e-5 and armature.max() <= 3 + 1e-5


def test_reacher_fingertip_matches_mujoco_site():
    robot = ReacherArm()
    m = robot.model
    d = mujoco.MjData(m)
    for q in np.random.default_rng(5).uniform(-4, 4, (20, 2)):
        d.qpos[:] = np.float32(q)
        mujoco.mj_kinematics(m, d)
        tip = robot.fingertip(jnp.asarray(q, jnp.float32))
        np.testing.assert_allclose(tip, d.site_xpos[robot.tip_site, :2], atol=2e-6)


#: the ids this package registers (an installed plugin's tasks need not have a robot)
OUR_IDS = [
    i for i in jaxenvs.list_envs() if jaxenvs.spec(i).factory.__module__.startswith("jaxenvs.")
]


@pytest.mark.parametrize("env_id", OUR_IDS)
def test_task_observation_is_a_function_of_readings_from_elsewhere(env_id):
    """Each task's observation, given host (numpy) readings and its own state, is the
    observation its env returns: what a loop driving a real robot feeds it."""
    env = jaxenvs.make(env_id, physics="c")
    state = jax.jit(env.reset)(jax.random.key(0))
    readings = {k: np.asarray(v) for k, v in env.robot.sense(state.data).items()}
    assert set(readings) == set(env.robot.sensors) - {
        n for n, s in env.robot.sensors.items() if not s.from_state
    }
    task = env.task_state(state.data, state.extras)
    np.testing.assert_allclose(env.observation(readings, task), state.obs, atol=1e-6)


@pytest.mark.full  # an MJX compile of the walker
def test_mjx_fills_sensordata_when_asked():
    robot = Hexapod(sensordata=True)
    sim = robot.make_sim(0.01, 5, scene=robot.scene())  # standing on its floor
    qpos = robot.qpos(jnp.array([0.0, 0.0, 0.14]), jnp.array([1.0, 0.0, 0.0, 0.0]), jnp.zeros(18))
    ctrl = robot.command(jnp.full(18, 0.3))
    out = jax.jit(sim.step)(sim.mx, sim.init_data(qpos=qpos, qvel=jnp.zeros(24)), ctrl)
    m = sim.physics_mj_model
    d = mujoco.MjData(m)
    d.qpos[:] = np.asarray(qpos, np.float64)
    d.ctrl[:] = np.asarray(ctrl, np.float64)
    for _ in range(5):
        mujoco.mj_step(m, d)
    accel = robot.sensors["imu_accel"]
    want = d.sensordata[accel.adr : accel.adr + 3]
    np.testing.assert_allclose(robot.sense(out)["imu_accel"], want, rtol=1e-3, atol=1e-3)
    assert np.linalg.norm(want) > 1.0
