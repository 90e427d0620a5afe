"""Reacher: a 2-link planar arm (``robots/reacher.xml``) reaching a random target.

``Reacher-v0``

* Robot: two hinges about z, links 0.1 m each (reach 0.2 m), capsule links of about
  0.036 kg, joint armature 1 and damping 1, no joint limits (angles wrap freely), motors
  of gear 200: ``ctrl`` in [-1, 1] gives +-200 N m. These are Gymnasium Reacher's
  dynamics (its second link is 0.11 m), so that returns compare with Reacher-v5.
* Target: a mocap body (moved by the task, never simulated), drawn uniformly in the disk
  of radius ``params.target_radius`` (0.2 by default: everything the arm can reach) at
  every reset, at the arm's height.
* Observation (10), the order of Gymnasium's Reacher-v5::

      0  cos(joint0)          5  target y
      1  cos(joint1)          6  joint0 velocity (rad/s)
      2  sin(joint0)          7  joint1 velocity (rad/s)
      3  sin(joint1)          8  fingertip x - target x
      4  target x             9  fingertip y - target y

  (Reacher-v5 has the same ten entries; v4 added a constant-zero z difference.)
* Action: Box(2) in [-1, 1], the two motor commands.
* Reward: ``-|fingertip - target| - ctrl_cost_weight * |a|^2`` with the distance taken
  AFTER the action's control step (Gymnasium v5 takes it before, i.e. rewards the
  previous state; over an episode the two differ by d(start) - d(end), at most 0.4 and
  about 0.1 for a policy that reaches). Defaults (weight 0.1, 50 steps) are Reacher-v5's,
  so its "solved" return of -3.75 applies.
* Termination: none. Truncation: ``episode_length`` (50) steps.
* Start: joint angles uniform in +-``init_angle_noise`` (0.1 rad), velocities uniform in
  +-``init_velocity_noise`` (0.005 rad/s), as Reacher-v5.
* Timing: 0.02 s per control step as ONE Euler substep of 0.02 s (``substeps=1``;
  Gymnasium runs two RK4 steps of 0.01 s). ``timestep=0.01, substeps=2`` halves the
  integration error at half the throughput.
* Physics: no contacts, no constraints, gravity off (no torque about vertical hinges),
  Euler with damping integrated implicitly, sparse mass matrix (``jacobian="sparse"``:
  MJX factorises M with plain JAX ops, no LAPACK call per step). Each physics step is
  ``mjx.step`` (checked against ``mujoco.mj_step`` in ``tests/test_parity.py``).
  ``mjx.step`` leaves positions one substep behind ``qpos``, so the fingertip is computed
  from ``qpos`` by the arm's planar kinematics (:func:`planar_arm` reads the link offsets
  from the MJCF and refuses any other robot; ``tests/test_reacher.py`` checks it against
  MuJoCo's site position); a reset needs no kinematics pass.

Params (``ReacherParams``): ``model`` holds the MJX model fields ``body_mass``,
``body_inertia``, ``dof_armature``, ``dof_damping`` and ``actuator_gear``;
``target_radius`` bounds the target disk. ``sample_params`` (used by
``make(..., num_envs=N, randomize=True)`` at each env's every reset) scales the links'
masses and inertias together by ``mass_scale``, armature by ``armature_scale``, damping
by ``damping_scale``, motor gear by ``gain_scale`` (one factor per link, dof or motor),
and draws ``target_radius`` uniformly in ``target_radius_range``. No friction: the
reacher has no contacts.
"""

from __future__ import annotations

import dataclasses
import math

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
from flax import struct
from mujoco import mjx

from jaxenvs import randomize
from jaxenvs.config import require
from jaxenvs.core import Env, NoExtras, TaskConfig
from jaxenvs.randomize import Range
from jaxenvs.robots import robot_xml
from jaxenvs.sim import Sim

MODEL_FIELDS = ("body_mass", "body_inertia", "dof_armature", "dof_damping", "actuator_gear")
LINK_LENGTH = 0.1
REACH = 2 * LINK_LENGTH
ARM_BODIES = ("link0", "link1")


class ReacherParams(struct.PyTreeNode):
    """Randomisable physics and task quantities.

    Attributes:
      model: MJX model fields swapped in at every step (see ``MODEL_FIELDS``).
      target_radius: targets are drawn uniformly in the disk of this radius (m).
    """

    model: dict[str, jax.Array]
    target_radius: jax.Array


@dataclasses.dataclass(frozen=True)
class ReacherConfig(TaskConfig):
    """``Reacher-v0``.

    Attributes:
      episode_length: steps per episode (50 = 1 s, as Reacher-v5).
      timestep, substeps: physics; the control period is their product (0.02 s).
      ctrl_cost_weight: weight of ``|a|^2`` in the reward (Reacher-v5: 0.1).
      target_radius: default radius of the target disk (m), at most the reach 0.2.
      init_angle_noise: initial joint angles uniform in +- this (rad).
      init_velocity_noise: initial joint velocities uniform in +- this (rad/s).
      mass_scale: randomisation: factor on each link's mass and inertia.
      armature_scale: randomisation: factor on each joint's armature.
      damping_scale: randomisation: factor on each joint's damping.
      gain_scale: randomisation: factor on each motor's gear (torque per unit action).
      target_radius_range: randomisation: ``target_radius`` drawn uniformly in it.
    """

    episode_length: int = 50
    timestep: float = 0.02
    substeps: int = 1
    ctrl_cost_weight: float = 0.1
    target_radius: float = REACH
    init_angle_noise: float = 0.1
    init_velocity_noise: float = 0.005
    mass_scale: Range = (0.8, 1.2)
    armature_scale: Range = (0.8, 1.2)
    damping_scale: Range = (0.8, 1.2)
    gain_scale: Range = (0.8, 1.2)
    target_radius_range: Range = (REACH, REACH)

    def validate(self) -> None:
        super().validate()
        require(self.ctrl_cost_weight >= 0, "ctrl_cost_weight", "must be >= 0")
        require(
            0 < self.target_radius <= REACH + 1e-9,
            "target_radius",
            f"must be in (0, {REACH}] (the arm's reach)",
        )
        require(self.init_angle_noise >= 0, "init_angle_noise", "must be >= 0")
        require(self.init_velocity_noise >= 0, "init_velocity_noise", "must be >= 0")
        for name in ("mass_scale", "armature_scale", "damping_scale", "gain_scale"):
            randomize.check_range(name, getattr(self, name), positive=True)
        randomize.check_range(
            "target_radius_range", self.target_radius_range, positive=True, max_high=REACH + 1e-9
        )


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


def _rotate(angle: jax.Array, v: jax.Array) -> jax.Array:
    c, s = jnp.cos(angle), jnp.sin(angle)
    return jnp.stack([c * v[0] - s * v[1], s * v[0] + c * v[1]])


class Reacher(Env[ReacherConfig]):
    """``Reacher-v0``: put the fingertip of a 2-link planar arm on a random target.

    See the module docstring for the full spec (observation layout, reward, timing).
    ``extras`` is :class:`~jaxenvs.core.NoExtras` (the target lives in ``data.mocap_pos``).
    """

    #: physics="auto" on a CPU: C, and MJX from 4,096 envs (benchmarks/RESULTS.md,
    #: "physics='auto' on a CPU")
    cpu_physics = "c"
    cpu_mjx_from = 4096

    metric_keys = ("distance", "ctrl_cost")
    scan_unroll = 2

    def __init__(self, config: ReacherConfig | None = None) -> None:
        config = config or ReacherConfig()
        super().__init__(config, Sim(robot_xml("reacher"), config.timestep, config.substeps))
        m = self.sim.mj_model
        off = mujoco.mjtDisableBit
        needed = off.mjDSBL_CONSTRAINT | off.mjDSBL_CONTACT
        if m.opt.integrator != mujoco.mjtIntegrator.mjINT_EULER or (
            m.opt.disableflags & needed != needed
        ):
            raise ValueError("reacher.xml must use Euler with constraints and contacts disabled")
        self._tip = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_SITE, "fingertip")
        self._base, self._link, self._tip_offset = (
            jnp.asarray(v, jnp.float32) for v in planar_arm(m, self._tip)
        )
        arm = [mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, b) for b in ARM_BODIES]
        self._arm_mask = jnp.asarray(np.isin(np.arange(m.nbody), arm))
        self._params = ReacherParams(
            model=self.sim.default_fields(MODEL_FIELDS),
            target_radius=jnp.asarray(config.target_radius, jnp.float32),
        )
        self._target_z = float(
            m.body_pos[mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, "target")][2]
        )

    observation_size = 10
    action_size = 2

    @property
    def default_params(self) -> ReacherParams:
        return self._params

    def sample_params(self, key: jax.Array) -> ReacherParams:
        """Params drawn from the config's randomisation ranges (see the module docstring)."""
        c = self.config
        mass_key, field_key, radius_key = jax.random.split(key, 3)
        base = self._params.model
        mass, inertia = randomize.scale_mass(
            mass_key, base["body_mass"], base["body_inertia"], c.mass_scale, self._arm_mask
        )
        ranges = {
            "dof_armature": c.armature_scale,
            "dof_damping": c.damping_scale,
            "actuator_gear": c.gain_scale,
        }
        fields = randomize.scale_fields(field_key, base, ranges)
        fields.update(body_mass=mass, body_inertia=inertia)
        radius = randomize.uniform(radius_key, c.target_radius_range)
        return ReacherParams(model=fields, target_radius=radius)

    def sample_target(self, key: jax.Array, radius: jax.Array) -> jax.Array:
        """A point uniform in the disk of ``radius`` (area-uniform: r = R sqrt(u))."""
        return _disk_point(jax.random.uniform(key, (2,)), radius)

    def _init(self, key: jax.Array, params: ReacherParams) -> tuple[mjx.Data, NoExtras]:
        c = self.config
        # one draw for all six numbers: each random call is a loop XLA compiles on its own
        u = jax.random.uniform(key, (6,))
        qpos = c.init_angle_noise * (2.0 * u[0:2] - 1.0)
        qvel = c.init_velocity_noise * (2.0 * u[2:4] - 1.0)
        target = _disk_point(u[4:6], params.target_radius)
        mocap = jnp.concatenate([target, jnp.full((1,), self._target_z)])[None]
        return self.sim.init_data(qpos=qpos, qvel=qvel, mocap_pos=mocap), NoExtras()

    def _act(
        self,
        key: jax.Array,
        data: mjx.Data,
        extras: NoExtras,
        action: jax.Array,
        params: ReacherParams,
    ) -> tuple[mjx.Data, NoExtras]:
        return self.sim.step(self.sim.model_with(params.model), data, action), extras

    def fingertip(self, data: mjx.Data) -> jax.Array:
        """The fingertip's (x, y) at ``data.qpos``: the arm's planar forward kinematics."""
        q0, q1 = data.qpos[0], data.qpos[1]
        return self._base + _rotate(q0, self._link) + _rotate(q0 + q1, self._tip_offset)

    def _observe(
        self, key: jax.Array, data: mjx.Data, extras: NoExtras, params: ReacherParams
    ) -> jax.Array:
        target = data.mocap_pos[0, :2]
        q = data.qpos
        return jnp.concatenate(
            [jnp.cos(q), jnp.sin(q), target, data.qvel, self.fingertip(data) - target]
        )

    def _reward(
        self,
        prev: mjx.Data,
        data: mjx.Data,
        action: jax.Array,
        extras: NoExtras,
        params: ReacherParams,
    ) -> tuple[jax.Array, dict[str, jax.Array]]:
        distance = jnp.linalg.norm(self.fingertip(data) - data.mocap_pos[0, :2])
        ctrl_cost = self.config.ctrl_cost_weight * jnp.sum(jnp.square(action))
        reward = -distance - ctrl_cost
        return reward, {"distance": distance, "ctrl_cost": ctrl_cost}


def _disk_point(u: jax.Array, radius: jax.Array) -> jax.Array:
    """The point of the disk of ``radius`` at uniform numbers ``u`` (2,): area-uniform, r =
    R sqrt(u0), angle 2 pi u1."""
    r = radius * jnp.sqrt(u[0])
    phi = 2 * math.pi * u[1]
    return jnp.stack([r * jnp.cos(phi), r * jnp.sin(phi)])
