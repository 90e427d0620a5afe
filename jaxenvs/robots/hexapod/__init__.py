"""The hexapod: a six-legged walker (``hexapod.xml``) and one of its legs on a fixed base
(``hexapod_leg.xml``, the rig). Both MJCFs live here because they are the same leg
hardware: one forward kinematics (:func:`leg_tip`), one servo map, one randomisation.

Robot: a 1.0 kg box body (24 x 16 x 5 cm) and six legs of three servo-driven joints in the
proportions of small hobby hexapod kits: hip yaw (+-0.46 rad), femur and tibia pitch
(+-1.57 rad, positive lifts the leg); coxa 4 cm, femur 8 cm, foot tip 13.2 cm below the
knee; about 2.0 kg in all. Legs in joint order: lf, lm, lr, rf, rm, rr (left/right,
front/middle/rear), each hip, femur, tibia.

Actuators: MuJoCo position servos (kp 20 N m/rad, torque limited to +-2 N m, joint damping
0.3, armature 0.005 kg m^2). Command map: an action in [-1, 1] is a joint POSITION target,
linear over the joint range (:func:`servo_targets`; 0 = the standing pose: coxa and femur
horizontal, tibia vertical).

Sensors (MJCF ``<sensor>``): per joint an encoder, ``<leg>_<joint>_pos`` (``jointpos``,
rad) and ``<leg>_<joint>_vel`` (``jointvel``, rad/s); an IMU on the site ``imu`` at the
torso's origin: ``imu_quat`` (``framequat``, torso -> world, w x y z), ``imu_gyro``
(``gyro``, rad/s, body frame), ``imu_accel`` (``accelerometer``, m/s^2, body frame; read
from ``sensordata``: one substep old, and only from ``Hexapod(sensordata=True)``).
PRIVILEGED (simulator only): ``torso_vel`` (``velocimeter``: the torso's linear velocity
in the body frame, m/s) and ``torso_pos`` (``framepos``: its world position, m; the
height is ``torso_pos[2]``). The rig has the encoders only: ``hip_pos``, ``femur_pos``,
``tibia_pos``, ``hip_vel``, ``femur_vel``, ``tibia_vel``.

Randomisable fields (:data:`WALK_FIELDS`; the rig: :data:`LEG_FIELDS`, no contacts):
``body_mass`` and ``body_inertia`` scaled together per body by ``mass_scale``, each foot
pair's ``pair_friction`` by ``friction_scale``, each servo's kp (``actuator_gainprm`` and
``actuator_biasprm`` together) by ``gain_scale``, each joint's ``dof_damping`` by
``damping_scale`` (:class:`HexapodRanges`).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping
from typing import Any

import jax
import jax.numpy as jnp
import mujoco
import numpy as np

from jaxenvs import randomize
from jaxenvs.randomize import Range
from jaxenvs.robots import robot_xml
from jaxenvs.robots.base import (
    Randomization,
    Robot,
    gravity_in_body,
    quat_to_mat,
    world_to_body,
)
from jaxenvs.scenes import Flat, Ground, Marker, Scene

__all__ = [
    "COXA",
    "FEMUR",
    "JOINT_RANGE",
    "LEGS",
    "LEG_FIELDS",
    "LEG_RANGE",
    "STAND_HEIGHT",
    "TIP",
    "WALK_FIELDS",
    "Hexapod",
    "HexapodLeg",
    "HexapodRanges",
    "gravity_in_body",
    "leg_tip",
    "quat_to_mat",
    "servo_targets",
    "world_to_body",
]

COXA, FEMUR, TIP = 0.04, 0.08, 0.132  # m: hip->femur joint, femur->tibia joint, knee->tip
LEG_RANGE = (0.46, 1.57, 1.57)  # half-ranges of hip yaw, femur, tibia (rad)
#: a host constant (numpy): a JAX array here would start JAX's backends at import time
JOINT_RANGE = np.asarray(LEG_RANGE * 6, np.float32)
STAND_HEIGHT = 0.135  # torso height when standing on all six feet at zero angles (m)
LEGS = ("lf", "lm", "lr", "rf", "rm", "rr")
WALK_FIELDS = (
    "body_mass",
    "body_inertia",
    "dof_damping",
    "actuator_gainprm",
    "actuator_biasprm",
    "pair_friction",
)
LEG_FIELDS = WALK_FIELDS[:-1]


def leg_tip(q: jax.Array) -> jax.Array:
    """Forward kinematics of one leg: foot tip in the hip's frame for angles ``q`` (3,)."""
    reach = COXA + FEMUR * jnp.cos(q[1]) + TIP * jnp.sin(q[1] + q[2])
    height = FEMUR * jnp.sin(q[1]) - TIP * jnp.cos(q[1] + q[2])
    return jnp.stack([reach * jnp.cos(q[0]), reach * jnp.sin(q[0]), height])


def servo_targets(action: jax.Array) -> jax.Array:
    """Joint position targets (rad) of actions in [-1, 1]: linear over each joint range."""
    return action * JOINT_RANGE[: action.shape[0]]


@dataclasses.dataclass(frozen=True)
class HexapodRanges(Randomization):
    """The hexapod's randomisation ranges (factors on the defaults, one draw per body,
    foot pair, servo, joint).

    Attributes:
      mass_scale: factor on each body's mass and inertia.
      friction_scale: factor on each foot-floor pair's friction (walker only).
      gain_scale: factor on each servo's kp.
      damping_scale: factor on each joint's damping.
    """

    mass_scale: Range = (0.8, 1.2)
    friction_scale: Range = (0.7, 1.3)
    gain_scale: Range = (0.8, 1.2)
    damping_scale: Range = (0.7, 1.3)

    def check_ranges(self) -> None:
        for name in ("mass_scale", "friction_scale", "gain_scale", "damping_scale"):
            randomize.check_range(name, getattr(self, name), positive=True)


def sample_hexapod_fields(
    key: jax.Array, fields: Mapping[str, jax.Array], config: HexapodRanges
) -> dict[str, jax.Array]:
    """``fields`` (the defaults) randomised by ``config``'s ranges (module docstring).

    All factors come from one PRNG call (:func:`jaxenvs.randomize.uniforms`), in the order
    mass (per body), friction (per foot pair, when ``fields`` has ``pair_friction``), kp
    (per servo), damping (per joint).
    """
    out = dict(fields)
    draws = [(config.mass_scale, out["body_mass"].shape[:1])]
    if "pair_friction" in out:
        draws.append((config.friction_scale, out["pair_friction"].shape[:1]))
    draws.append((config.gain_scale, out["actuator_gainprm"].shape[:1]))
    draws.append((config.damping_scale, out["dof_damping"].shape[:1]))
    factors = randomize.uniforms(key, draws)
    mass = factors.pop(0)
    out["body_mass"] = randomize.scaled(out["body_mass"], mass)
    out["body_inertia"] = randomize.scaled(out["body_inertia"], mass)
    if "pair_friction" in out:
        out["pair_friction"] = randomize.scaled(out["pair_friction"], factors.pop(0))
    kp, damping = factors
    out["actuator_gainprm"] = out["actuator_gainprm"].at[:, 0].multiply(kp)
    out["actuator_biasprm"] = out["actuator_biasprm"].at[:, 1].multiply(kp)
    out["dof_damping"] = randomize.scaled(out["dof_damping"], damping)
    return out


class _HexapodServos(Robot):
    """What the walker and the rig share: servo command map and randomisation."""

    def command(self, action: jax.Array) -> jax.Array:
        """Joint position targets of actions in [-1, 1] (:func:`servo_targets`)."""
        return servo_targets(action)

    def sample_fields(
        self, key: jax.Array, fields: Mapping[str, jax.Array], config: Any
    ) -> dict[str, jax.Array]:
        return sample_hexapod_fields(key, fields, config)


class Hexapod(_HexapodServos):
    """The six-legged walker (``hexapod.xml``): a free-floating torso and 18 servos.

    ``qpos`` is the torso's free joint (position, quaternion) then the 18 joint angles in
    :data:`LEGS` order; :meth:`qpos` builds it.
    """

    xml = robot_xml("hexapod")
    privileged = frozenset({"torso_vel", "torso_pos"})
    fields = WALK_FIELDS
    #: the geoms that touch the ground (a scene pairs each with it): the feet, in
    #: :data:`LEGS` order (``pair_friction``'s order)
    feet = tuple(f"{leg}_foot" for leg in LEGS)

    def scene(
        self,
        ground: Ground | None = None,
        markers: tuple[Marker, ...] = (),
        max_contacts: int = 0,
        hfield_contact: str = "surface",
    ) -> Scene:
        """The hexapod standing on ``ground`` (default: a flat floor), its feet paired with
        it, with a task's ``markers``, MJX's contact budget (``Scene.max_contacts``) and
        MuJoCo C's collider on a heightfield (``Scene.hfield_contact``)."""
        return Scene(
            self.xml,
            ground or Flat(),
            contacts=self.feet,
            markers=markers,
            max_contacts=max_contacts,
            hfield_contact=hfield_contact,
        )

    def qpos(self, pos: jax.Array, quat: jax.Array, joints: jax.Array) -> jax.Array:
        """The state's positions: torso position (3, m), orientation (4, w x y z), joint
        angles (18, rad)."""
        return jnp.concatenate([pos, quat, joints])

    @staticmethod
    def upright(readings: Mapping[str, jax.Array]) -> jax.Array:
        """The vertical component of the torso's up axis (1 upright, 0 on its side)."""
        return quat_to_mat(readings["imu_quat"])[2, 2]

    @staticmethod
    def height(readings: Mapping[str, jax.Array]) -> jax.Array:
        """The torso's height (m; privileged)."""
        return readings["torso_pos"][2]


class HexapodLeg(_HexapodServos):
    """One hexapod leg bolted to a fixed base (``hexapod_leg.xml``): ``qpos`` is its three
    joint angles (hip, femur, tibia). :attr:`hip` is the hip's position in the world (m);
    the foot tip at angles ``q`` is ``hip + leg_tip(q)``."""

    xml = robot_xml("hexapod_leg")
    fields = LEG_FIELDS

    def __init__(self, sensordata: bool = False) -> None:
        super().__init__(sensordata)
        base = mujoco.mj_name2id(self.model, mujoco.mjtObj.mjOBJ_BODY, "base")
        #: the hip joint's position in the world (m), a host constant
        self.hip = np.asarray(self.model.body_pos[base], np.float32)
