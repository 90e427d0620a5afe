"""Reacher: the 2-link planar arm of :mod:`jaxenvs.robots.reacher` reaching a random target.

``Reacher-v0``

* Robot: :mod:`jaxenvs.robots.reacher` (two hinges about z, links 0.1 m each, reach 0.2 m,
  Gymnasium Reacher's dynamics; motors of gear 200: an action in [-1, 1] gives
  +-200 N m; encoders on both joints).
* Target: a mocap body (moved by the task, never simulated), drawn uniformly in the disk
  of radius ``params.target_radius`` (0.2 by default: everything the arm can reach) at
  every reset, at the arm's height.
* Observation (10), the order of Gymnasium's Reacher-v5, from the encoders' readings and
  the target (:meth:`Reacher.observation`)::

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
* Physics: each physics step is ``mjx.step`` (checked against ``mujoco.mj_step`` in
  ``tests/physics/test_parity.py``). The fingertip is the arm's planar kinematics of the encoder
  readings (:meth:`~jaxenvs.robots.reacher.ReacherArm.fingertip`, checked against MuJoCo's
  site position); a reset needs no kinematics pass.

Params (``ReacherParams``): ``model`` holds the MJX model fields ``body_mass``,
``body_inertia``, ``dof_armature``, ``dof_damping`` and ``actuator_gear``;
``target_radius`` bounds the target disk. ``sample_params`` (used by
``make(..., num_envs=N, randomize=True)`` at each env's every reset) draws ``model`` from
the robot's ranges (:class:`~jaxenvs.robots.reacher.ReacherRanges`: the links' masses and
inertias together by ``mass_scale``, armature by ``armature_scale``, damping by
``damping_scale``, motor gear by ``gain_scale``) and ``target_radius`` uniformly in
``target_radius_range``. No friction: the reacher has no contacts.
"""

from __future__ import annotations

import dataclasses
import math
from typing import TYPE_CHECKING

import jax
import jax.numpy as jnp
from flax import struct

from jaxenvs import randomize
from jaxenvs.config import require
from jaxenvs.core import Env, NoExtras, TaskConfig
from jaxenvs.randomize import Range
from jaxenvs.robots.base import Readings, RobotTask
from jaxenvs.robots.reacher import REACH, ReacherArm, ReacherRanges

if TYPE_CHECKING:
    from mujoco import mjx


class ReacherParams(struct.PyTreeNode):
    """Randomisable physics and task quantities.

    Attributes:
      model: MJX model fields swapped in at every step (the robot's ``FIELDS``).
      target_radius: targets are drawn uniformly in the disk of this radius (m).
    """

    model: dict[str, jax.Array]
    target_radius: jax.Array


@dataclasses.dataclass(frozen=True)
class ReacherConfig(ReacherRanges, TaskConfig):
    """``Reacher-v0``. The robot's randomisation ranges
    (:class:`~jaxenvs.robots.reacher.ReacherRanges`) are config fields too.

    Attributes:
      episode_length: steps per episode (50 = 1 s, as Reacher-v5).
      timestep, substeps: physics; the control period is their product (0.02 s).
      ctrl_cost_weight: weight of ``|a|^2`` in the reward (Reacher-v5: 0.1).
      target_radius: default radius of the target disk (m), at most the reach 0.2.
      init_angle_noise: initial joint angles uniform in +- this (rad).
      init_velocity_noise: initial joint velocities uniform in +- this (rad/s).
      target_radius_range: randomisation: ``target_radius`` drawn uniformly in it.
    """

    episode_length: int = 50
    timestep: float = 0.02
    substeps: int = 1
    ctrl_cost_weight: float = 0.1
    target_radius: float = REACH
    init_angle_noise: float = 0.1
    init_velocity_noise: float = 0.005
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
        randomize.check_range(
            "target_radius_range", self.target_radius_range, positive=True, max_high=REACH + 1e-9
        )


class Reacher(RobotTask, Env[ReacherConfig]):
    """``Reacher-v0``: put the fingertip of a 2-link planar arm on a random target.

    See the module docstring for the full spec (observation layout, reward, timing).
    ``extras`` is :class:`~jaxenvs.core.NoExtras` (the target lives in ``data.mocap_pos``).
    """

    #: physics="auto" on a CPU: C at every size (since the C engine writes back only the
    #: declared derived fields it was at least MJX's throughput at 1-16,384 envs on 2 and
    #: 16 cores; benchmarks/RESULTS.md, "physics='auto' on a CPU")
    #: every reading comes from qpos/qvel (the target is mocap_pos, an input)
    derived_fields: tuple[str, ...] | None = ()

    metric_keys = ("distance", "ctrl_cost")
    scan_unroll = 2

    robot: ReacherArm

    def __init__(self, config: ReacherConfig | None = None) -> None:
        config = config or ReacherConfig()
        self.robot = ReacherArm()
        super().__init__(config, self.robot.make_sim(config.timestep, config.substeps))
        self._params = ReacherParams(
            model=self.robot.default_fields(self.sim),
            target_radius=jnp.asarray(config.target_radius, jnp.float32),
        )

    observation_size = 10
    action_size = 2

    def sample_params(self, key: jax.Array) -> ReacherParams:
        """Params drawn from the config's randomisation ranges (see the module docstring):
        the robot's fields, and the target radius from the third of ``split(key, 3)``."""
        params = super().sample_params(key)
        radius_key = jax.random.split(key, 3)[2]
        radius = randomize.uniform(radius_key, self.config.target_radius_range)
        return params.replace(target_radius=radius)

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
        mocap = jnp.concatenate([target, jnp.full((1,), self.robot.target_z)])[None]
        return self.sim.init_data(qpos=qpos, qvel=qvel, mocap_pos=mocap), NoExtras()

    def _act(
        self,
        key: jax.Array,
        data: mjx.Data,
        extras: NoExtras,
        action: jax.Array,
        params: ReacherParams,
    ) -> tuple[mjx.Data, NoExtras]:
        ctrl = self.robot.command(action)
        return self.sim.step(self.sim.model_with(params.model), data, ctrl), extras

    def task_state(self, data: mjx.Data, extras: NoExtras) -> jax.Array:
        """The task's own input to :meth:`observation`: the target's (x, y) (m)."""
        return data.mocap_pos[0, :2]

    def observation(self, readings: Readings, target: jax.Array) -> jax.Array:
        """The observation (module docstring) of the encoders' ``readings`` and the
        target's (x, y)."""
        q = self.robot.joint_pos(readings)
        return jnp.concatenate(
            [
                jnp.cos(q),
                jnp.sin(q),
                target,
                self.robot.joint_vel(readings),
                self.robot.fingertip(q) - target,
            ]
        )

    def _reward(
        self,
        prev: mjx.Data,
        data: mjx.Data,
        action: jax.Array,
        extras: NoExtras,
        params: ReacherParams,
    ) -> tuple[jax.Array, dict[str, jax.Array]]:
        q = self.robot.joint_pos(self.robot.sense(data))
        distance = jnp.linalg.norm(self.robot.fingertip(q) - self.task_state(data, extras))
        ctrl_cost = self.config.ctrl_cost_weight * jnp.sum(jnp.square(action))
        reward = -distance - ctrl_cost
        return reward, {"distance": distance, "ctrl_cost": ctrl_cost}


def _disk_point(u: jax.Array, radius: jax.Array) -> jax.Array:
    """The point of the disk of ``radius`` at uniform numbers ``u`` (2,): area-uniform, r =
    R sqrt(u0), angle 2 pi u1."""
    r = radius * jnp.sqrt(u[0])
    phi = 2 * math.pi * u[1]
    return jnp.stack([r * jnp.cos(phi), r * jnp.sin(phi)])
