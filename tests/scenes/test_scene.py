"""The scene layer: the robot's MJCF holds the robot alone; a scene puts it on a ground."""

from __future__ import annotations

import dataclasses

import mujoco
import numpy as np
import pytest

import jaxenvs
from jaxenvs.robots.hexapod import Hexapod
from jaxenvs.scenes import MAX_CONTACTS, Flat, Marker, Scene


def _names(model: mujoco.MjModel, obj: mujoco.mjtObj, n: int) -> list[str]:
    return [mujoco.mj_id2name(model, obj, i) for i in range(n)]


def test_the_robot_mjcf_holds_no_ground():
    robot = mujoco.MjModel.from_xml_path(str(Hexapod.xml))
    assert robot.npair == 0 and robot.nlight == 0
    assert "floor" not in _names(robot, mujoco.mjtObj.mjOBJ_GEOM, robot.ngeom)


def test_a_scene_pairs_the_feet_with_its_ground():
    model = Hexapod().scene(markers=(Marker("target"),)).spec().compile()
    geoms = _names(model, mujoco.mjtObj.mjOBJ_GEOM, model.ngeom)
    pairs = [(geoms[a], geoms[b]) for a, b in zip(model.pair_geom1, model.pair_geom2, strict=True)]
    assert pairs == [("floor", foot) for foot in Hexapod.feet]
    assert model.nmocap == 1 and model.nlight == 1
    np.testing.assert_allclose(model.pair_friction[:, :3], [[1.0, 1.0, 0.005]] * 6)


def test_a_task_names_its_scene_and_its_ground():
    walker = jaxenvs.make("HexapodWalk-v0")
    joystick = jaxenvs.make("HexapodJoystick-v0")
    assert walker.sim.mj_model.nmocap == 1  # the target
    assert joystick.sim.mj_model.nmocap == 1  # the same scene (its marker unused)
    bodies = _names(walker.sim.mj_model, mujoco.mjtObj.mjOBJ_BODY, 3)
    assert bodies == ["world", "target", "torso"]  # markers first: the draws by body stay
    slippery = Flat(friction=(0.3, 0.005, 0.0001))
    env = type(joystick)(joystick.config, ground=slippery)
    np.testing.assert_allclose(env.sim.mj_model.pair_friction[:, 0], 0.3)
    assert isinstance(env.sim.source, Scene) and env.sim.source.ground == slippery


def test_a_scene_is_a_frozen_value():
    scene = Hexapod().scene()
    assert scene == Hexapod().scene() and hash(scene) == hash(Hexapod().scene())
    assert dataclasses.replace(scene, light=False).spec().compile().nlight == 0
    assert str(scene) == "hexapod.xml on flat"


def test_a_scene_sets_mjx_s_contact_budget():
    """``max_contacts`` is the model's ``max_contact_points`` numeric (MJX keeps that many
    of a step's deepest contacts); 0 writes none, a negative one is refused."""
    capped = Hexapod().scene(max_contacts=8).spec().compile()
    assert capped.nnumeric == 1
    assert mujoco.mj_id2name(capped, mujoco.mjtObj.mjOBJ_NUMERIC, 0) == MAX_CONTACTS
    np.testing.assert_array_equal(capped.numeric_data, [8.0])
    assert Hexapod().scene().spec().compile().nnumeric == 0
    with pytest.raises(ValueError, match="max_contacts must be >= 0"):
        Scene(Hexapod.xml, max_contacts=-1)
