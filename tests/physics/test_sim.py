"""The device model drops visual-only elements and nothing the physics or tasks read."""

from __future__ import annotations

import jax
import mujoco
import numpy as np
import pytest
from mujoco import mjx

import jaxenvs
from jaxenvs.physics.sim import physics_model
from jaxenvs.robots import robot_xml

ROBOTS = ("cartpole", "reacher", "hexapod", "hexapod_leg")


def _names(model: mujoco.MjModel, obj: mujoco.mjtObj, count: int) -> list[str]:
    return [mujoco.mj_id2name(model, obj, i) for i in range(count)]


@pytest.mark.parametrize("robot", ROBOTS)
def test_lean_model_keeps_ids_and_drops_visuals(robot):
    full = mujoco.MjModel.from_xml_path(str(robot_xml(robot)))
    lean = physics_model(robot_xml(robot))
    assert lean.ncam == 0 and lean.nlight == 0
    # colliding or paired geoms stay; every dropped geom collided with nothing
    kept = set(_names(lean, mujoco.mjtObj.mjOBJ_GEOM, lean.ngeom))
    for g in range(full.ngeom):
        name = mujoco.mj_id2name(full, mujoco.mjtObj.mjOBJ_GEOM, g)
        if full.geom_contype[g] or full.geom_conaffinity[g]:
            assert name in kept
    for obj, n in (
        (mujoco.mjtObj.mjOBJ_BODY, "nbody"),
        (mujoco.mjtObj.mjOBJ_JOINT, "njnt"),
        (mujoco.mjtObj.mjOBJ_SITE, "nsite"),
        (mujoco.mjtObj.mjOBJ_ACTUATOR, "nu"),
    ):
        assert _names(lean, obj, getattr(lean, n)) == _names(full, obj, getattr(full, n))
    for field in ("body_mass", "body_inertia", "body_ipos", "body_iquat", "dof_armature"):
        np.testing.assert_allclose(getattr(lean, field), getattr(full, field), atol=1e-12)
    assert lean.npair == full.npair


@pytest.mark.parametrize("robot", ROBOTS)
def test_lean_model_steps_like_the_full_one(robot):
    """MuJoCo C, float64: 200 steps of random controls from a perturbed start agree."""
    full = mujoco.MjModel.from_xml_path(str(robot_xml(robot)))
    lean = physics_model(robot_xml(robot))
    rng = np.random.default_rng(0)
    datas = [mujoco.MjData(m) for m in (full, lean)]
    start = full.qpos0 + 0.05 * rng.standard_normal(full.nq) * (full.nq == full.nv)
    ctrls = rng.uniform(-1, 1, (200, full.nu))
    for model, data in zip((full, lean), datas, strict=True):
        data.qpos[:] = start
        for ctrl in ctrls:
            data.ctrl[:] = ctrl
            mujoco.mj_step(model, data)
    np.testing.assert_allclose(datas[1].qpos, datas[0].qpos, atol=1e-9)
    np.testing.assert_allclose(datas[1].qvel, datas[0].qvel, atol=1e-7)
    np.testing.assert_allclose(datas[1].site_xpos, datas[0].site_xpos, atol=1e-9)
    assert datas[1].ncon == datas[0].ncon


def test_mass_of_a_dropped_geom_is_kept(tmp_path):
    # a geom that carries mass but collides with nothing: freezing the inertia keeps it
    xml = tmp_path / "m.xml"
    xml.write_text(
        """<mujoco><worldbody><body><joint type="hinge"/>
        <geom type="sphere" size="0.1" contype="0" conaffinity="0"/></body></worldbody></mujoco>"""
    )
    lean = physics_model(xml)
    full = mujoco.MjModel.from_xml_path(str(xml))
    assert lean.ngeom == 0 and lean.body_mass[1] == pytest.approx(full.body_mass[1])


def test_c_engine_hands_back_a_state_mujoco_reset_as_nan(tmp_path):
    """MuJoCo resets a state that goes bad (a state going in, or an acceleration, past
    mjMAXVAL) to the model's defaults and carries on; the C engine hands such an env back
    as NaN, as MJX would, so that the task flags it diverged."""
    from jaxenvs.physics.sim import CSim, Sim

    xml = tmp_path / "slider.xml"
    xml.write_text(
        """<mujoco><worldbody><body><joint name="x" type="slide" axis="1 0 0"/>
        <geom type="sphere" size="0.1" mass="1"/></body></worldbody>
        <actuator><motor joint="x" gear="1"/></actuator></mujoco>"""
    )
    sim = CSim(Sim(xml, timestep=0.01, substeps=4), threads=1)
    zero = np.zeros(1, np.float32)
    data = sim.init_data(zero, zero).replace(time=np.float32(0.5))
    calm = sim.step(None, data, zero + 1)
    assert np.isfinite(float(calm.qpos[0])) and float(calm.time) == pytest.approx(0.54)
    # a force of 1e11 N on 1 kg: the acceleration is past mjMAXVAL (1e10), MuJoCo resets
    wild = sim.step(None, data, zero + 1e11)
    assert np.isnan(float(wild.qpos[0])) and np.isnan(float(wild.qvel[0]))
    bad_in = sim.step(None, data.replace(qvel=zero + np.inf), zero)
    assert np.isnan(float(bad_in.qvel[0]))


@pytest.mark.parametrize("env_id", ["CartPole-v0", "Reacher-v0", "HexapodWalk-v0"])
def test_initial_data_from_the_host_model_equals_the_device_models(env_id):
    """Sim builds its template Data from the host model (no eager JAX ops); it must be the
    Data MJX makes from the device model: same tree, shapes, dtypes and values."""
    sim = jaxenvs.make(env_id, physics="mjx").sim
    ours, theirs = sim._data0, mjx.make_data(sim.mx)
    ours_leaves, ours_def = jax.tree.flatten(ours)
    their_leaves, their_def = jax.tree.flatten(theirs)
    assert ours_def == their_def
    for a, b in zip(ours_leaves, their_leaves, strict=True):
        assert isinstance(a, jax.Array)
        assert a.shape == b.shape and a.dtype == b.dtype
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))
