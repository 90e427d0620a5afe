"""The reacher (``reacher.xml``): a 2-link planar arm.

Robot: two hinges about z, links 0.1 m each (reach 0.2 m), capsule links of about
0.036 kg, joint armature 1 and damping 1, no joint limits (angles wrap freely). These are
Gymnasium Reacher's dynamics (its second link is 0.11 m), so that returns compare with
Reacher-v5. No contacts, no constraints, gravity off (no torque about vertical hinges),
Euler with damping integrated implicitly, sparse mass matrix (``jacobian="sparse"``: MJX
factorises M with plain JAX ops, no LAPACK call per step). The MJCF also holds a mocap
body ``target`` that a task moves (never simulated).

Actuators: two motors of gear 200; command map: ``ctrl`` = the action in [-1, 1], which
gives +-200 N m.

Sensors (MJCF ``<sensor>``): encoders ``joint0_pos``, ``joint1_pos`` (rad) and
``joint0_vel``, ``joint1_vel`` (rad/s). None is privileged. The fingertip is forward
kinematics of the encoders (:meth:`ReacherArm.fingertip`): ``mjx.step`` leaves positions
one substep behind ``qpos``, so nothing reads MuJoCo's site position.

Randomisable fields (:data:`FIELDS`, ranges :class:`ReacherRanges`): the links' masses
and inertias scaled together by ``mass_scale`` (one factor per link; the world and the
target keep theirs), armature by ``armature_scale``, damping by ``damping_scale``, motor
gear by ``gain_scale`` (one factor per dof or motor). No friction: no contacts.
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
from jaxenvs.robots.base import Randomization, Robot

FIELDS = ("body_mass", "body_inertia", "dof_armature", "dof_damping", "actuator_gear")
LINK_LENGTH = 0.1
REACH = 2 * LINK_LENGTH
ARM_BODIES = ("link0", "link1")


@dataclasses.dataclass(frozen=True)
class ReacherRanges(Randomization):
    """The reacher's randomisation ranges (factors on the defaults).

    Attributes:
      mass_scale: factor on each link's mass and inertia.
      armature_scale: factor on each joint's armature.
      damping_scale: factor on each joint's damping.
      gain_scale: factor on each motor's gear (torque per unit action).
    """

    mass_scale: Range = (0.8, 1.2)
    armature_scale: Range = (0.8, 1.2)
    damping_scale: Range = (0.8, 1.2)
    gain_scale: Range = (0.8, 1.2)

    def check_ranges(self) -> None:
        for name in ("mass_scale", "armature_scale", "damping_scale", "gain_scale"):
            randomize.check_range(name, getattr(self, name), positive=True)


def planar_arm(model: mujoco.MjModel, site: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(base, link, tip) offsets in the plane of a 2-hinge arm whose joints turn about z.

    The fingertip of such an arm at angles ``q`` is ``base + R(q0) link + R(q0 + q1) tip``
    (``R`` a planar rotation): ``base`` is the first body's position, ``link`` the second
    body's offset in the first, ``tip`` the site's offset in the second. Raises ValueError
    if the model is not that arm (another joint type or axis, rotated bodies, a joint away
    from its body's origin, the first body not on the world, or the site on another body).
    """
    if model.njnt != 2 or model.nq != 2:
        raise ValueError(f"expected a 2-joint arm, got {model.njnt} joints")
    bodies = [int(b) for b in model.jnt_bodyid]
    parents = [int(model.body_parentid[b]) for b in bodies]
    if parents != [0, bodies[0]] or int(model.site_bodyid[site]) != bodies[1]:
        raise ValueError("expected a chain: the world, joint 0's body, joint 1's body, the site")
    hinge = mujoco.mjtJoint.mjJNT_HINGE
    if any(int(t) != hinge for t in model.jnt_type) or not np.allclose(model.jnt_axis, [0, 0, 1]):
        raise ValueError("expected two hinges about z")
    if not np.allclose(model.jnt_pos, 0) or not np.allclose(model.body_quat[bodies], [1, 0, 0, 0]):
        raise ValueError("expected unrotated bodies with joints at their origins")
    return (
        np.asarray(model.body_pos[bodies[0], :2]),
        np.asarray(model.body_pos[bodies[1], :2]),
        np.asarray(model.site_pos[site, :2]),
    )


def _rotate(angle: jax.Array, v: jax.Array | np.ndarray) -> jax.Array:
    c, s = jnp.cos(angle), jnp.sin(angle)
    return jnp.stack([c * v[0] - s * v[1], s * v[0] + c * v[1]])


class ReacherArm(Robot):
    """The 2-link planar arm (module docstring). ``qpos``/``qvel`` are (joint0, joint1).

    Attributes:
      tip_site: id of the ``fingertip`` site.
      target_z: height of the ``target`` mocap body (the arm's plane, m).
    """

    xml = robot_xml("reacher")
    fields = FIELDS

    def __init__(self, sensordata: bool = False) -> None:
        super().__init__(sensordata)
        m = self.model
        off = mujoco.mjtDisableBit
        needed = off.mjDSBL_CONSTRAINT | off.mjDSBL_CONTACT
        if m.opt.integrator != mujoco.mjtIntegrator.mjINT_EULER or (
            m.opt.disableflags & needed != needed
        ):
            raise ValueError("reacher.xml must use Euler with constraints and contacts disabled")
        self.tip_site = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_SITE, "fingertip")
        self._base, self._link, self._tip = (
            np.asarray(v, np.float32) for v in planar_arm(m, self.tip_site)
        )
        arm = [mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, b) for b in ARM_BODIES]
        self._arm_mask = np.isin(np.arange(m.nbody), arm)
        target = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, "target")
        self.target_z = float(m.body_pos[target][2])

    def fingertip(self, q: jax.Array) -> jax.Array:
        """The fingertip's (x, y) at joint angles ``q`` (2,): planar forward kinematics."""
        q0, q1 = q[0], q[1]
        return jnp.asarray(self._base) + _rotate(q0, self._link) + _rotate(q0 + q1, self._tip)

    def sample_fields(
        self, key: jax.Array, fields: Mapping[str, jax.Array], config: Any
    ) -> dict[str, jax.Array]:
        """``fields`` randomised by ``config``'s :class:`ReacherRanges`. Draws from the
        first two keys of ``jax.random.split(key, 3)``; the third is the task's
        (Reacher-v0 draws its target radius from it)."""
        mass_key, field_key, _ = jax.random.split(key, 3)
        mass, inertia = randomize.scale_mass(
            mass_key,
            fields["body_mass"],
            fields["body_inertia"],
            config.mass_scale,
            jnp.asarray(self._arm_mask),
        )
        ranges = {
            "dof_armature": config.armature_scale,
            "dof_damping": config.damping_scale,
            "actuator_gear": config.gain_scale,
        }
        out = randomize.scale_fields(field_key, fields, ranges)
        out.update(body_mass=mass, body_inertia=inertia)
        return out
