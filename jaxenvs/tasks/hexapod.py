"""Hexapod tasks over :mod:`jaxenvs.robots.hexapod`: the six-legged walker and one of its
legs on a fixed base (the rig).

=====================  =============================================================
``HexapodWalk-v0``      walk from target to target (a new one drawn on arrival); falls end
                        the episode
``HexapodOneLeg-v0``    put one leg's foot tip on a reachable target; no contacts
=====================  =============================================================

The robot (geometry, servos, sensors, randomisable fields) is described in
:mod:`jaxenvs.robots.hexapod`. Actions in [-1, 1] are the robot's command map: joint
POSITION targets over each joint range (0 = the standing pose): a zero action holds a
stable stance. Each task's observation is :meth:`observation` of the robot's readings
(:meth:`~jaxenvs.robots.base.Robot.sense`) and the task's own state (:meth:`task_state`:
the target).

Physics for MJX speed on CPU (measurements in benchmarks/NOTES.md): the only collisions
are six explicit foot-floor pairs (condim 3, pyramidal cone); joints are unlimited (no
limit rows: the servo range is the joint range); Euler integration with damping implicit;
the CG solver (``solver_iterations`` and ``ls_iterations`` from the config) with a SPARSE
mass matrix, so that no step calls LAPACK (MJX's Newton solver and dense factorisations
do). MuJoCo does not evaluate the MJCF's sensors in the physics steps (no task reads
``sensordata``).

Params (``HexapodParams``): ``model`` holds MJX model fields ``body_mass``,
``body_inertia``, ``dof_damping``, ``actuator_gainprm``, ``actuator_biasprm`` and
(walker only) ``pair_friction``; ``target_range`` is the task's target range.
``sample_params`` draws ``model`` from the config's ranges (:class:`HexapodRanges`): each
body's mass and inertia together by ``mass_scale``, each foot pair's friction by
``friction_scale``, each servo's kp (gain and bias together) by ``gain_scale`` and each
joint's damping by ``damping_scale``.
"""

from __future__ import annotations

import dataclasses
import math
from typing import TYPE_CHECKING

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
from flax import struct

from jaxenvs import randomize
from jaxenvs.config import require
from jaxenvs.core import Env, TaskConfig
from jaxenvs.randomize import Range
from jaxenvs.robots.base import Readings, RobotTask, gravity_in_body, world_to_body
from jaxenvs.robots.hexapod import JOINT_RANGE, Hexapod, HexapodLeg, HexapodRanges, leg_tip

if TYPE_CHECKING:
    from mujoco import mjx

#: HexapodWalk-v0's observation noise at ``obs_noise=1``, per entry: joint angles (rad),
#: joint velocities (rad/s), height (m), gravity direction, body velocity (m/s), body
#: angular velocity (rad/s), target direction
OBS_NOISE = np.concatenate(
    [
        np.full(18, 0.02),
        np.full(18, 0.5),
        [0.005],
        np.full(3, 0.03),
        np.full(3, 0.05),
        np.full(3, 0.2),
        np.full(3, 0.02),
    ]
).astype(np.float32)


class HexapodParams(struct.PyTreeNode):
    """Randomisable physics and task quantities.

    Attributes:
      model: MJX model fields swapped in at every step.
      target_range: (low, high) of each target's distance from the body where it is
        drawn (walker, m: at reset and at each waypoint) or of the target posture's joint
        angles as fractions of each joint's half-range (one leg).
    """

    model: dict[str, jax.Array]
    target_range: jax.Array


@dataclasses.dataclass(frozen=True)
class HexapodRandomization(HexapodRanges, TaskConfig):
    """Fields shared by both hexapod configs: the robot's randomisation ranges
    (:class:`~jaxenvs.robots.hexapod.HexapodRanges`: ``mass_scale``, ``friction_scale``,
    ``gain_scale``, ``damping_scale``) and the physics timing.

    Attributes:
      timestep, substeps: physics; the control period is their product (0.05 s, what
        hobby servos sustain).
    """

    timestep: float = 0.01
    substeps: int = 5


def _solver_edit(iterations: int, ls_iterations: int):  # type: ignore[no-untyped-def]
    def edit(model: mujoco.MjModel) -> None:
        model.opt.iterations = iterations
        model.opt.ls_iterations = ls_iterations

    return edit


# -------------------------------------------------------------------------- HexapodWalk-v0
def _target_offset(u: jax.Array, target_range: jax.Array) -> jax.Array:
    """A target's horizontal offset (2,) from where it is drawn (m): at a distance in
    ``target_range``, in a uniformly random direction, from two uniforms ``u`` in [0, 1)."""
    low, high = target_range[0], target_range[1]
    dist = low + (high - low) * u[0]
    angle = math.pi * (2.0 * u[1] - 1.0)
    return jnp.stack([dist * jnp.cos(angle), dist * jnp.sin(angle)])


@dataclasses.dataclass(frozen=True)
class WalkConfig(HexapodRandomization):
    """``HexapodWalk-v0``.

    Attributes:
      episode_length: 1000 steps of 0.05 s (50 s).
      solver_iterations, ls_iterations: CG solver iterations and line-search steps of the
        contact solve.
      target_distance: each target (at reset, and each waypoint) is drawn at a distance
        from the body uniform in this range (m), in a uniformly random direction; its low
        end must exceed ``waypoint_radius``, so that a new target is never reached at once.
      progress_weight: weight of the progress term (metres per second toward the target).
      energy_weight: weight of the servos' mechanical power, sum |torque x joint speed| (W).
      alive_bonus: reward per step while not fallen.
      tilt_weight: weight of the tilt penalty ``1 - up_z`` (0 upright, 0.29 at 45 degrees),
        with ``up_z`` the vertical component of the body's up axis.
      spin_weight: weight of the penalty on the body's squared roll and pitch rates
        (rad^2/s^2, body frame); yaw (turning) is free.
      min_height: the episode ends when the body's height falls below this (m).
      min_upright: ... or when the body's z axis' vertical component falls below this
        (0.7: tilted more than ~45 degrees; 0 would be lying on its side).
      init_joint_noise: initial joint angles uniform in +- this (rad) around the stance.
      init_height: initial body height (m): the feet start just above the floor.
      action_noise: std of Gaussian noise added to each action before it is clipped to
        [-1, 1] (fractions of the joint's half-range; 0: none).
      obs_noise: std of Gaussian observation noise as a multiple of :data:`OBS_NOISE`
        (per-entry sensor scales; 0: none). Both draw from the hooks' keys.
      waypoint_radius: a target counts as reached when the body centre comes within this
        horizontal distance of it (m; about a body length), and a new target is drawn
        (waypoints); 0: one target per episode, never replaced.
    """

    episode_length: int = 1000
    solver_iterations: int = 6
    ls_iterations: int = 3
    target_distance: Range = (1.0, 3.0)
    progress_weight: float = 1.0
    energy_weight: float = 0.002
    alive_bonus: float = 0.05
    tilt_weight: float = 0.0
    spin_weight: float = 0.0
    min_height: float = 0.06
    min_upright: float = 0.7
    init_joint_noise: float = 0.05
    init_height: float = 0.14
    action_noise: float = 0.0
    obs_noise: float = 0.0
    waypoint_radius: float = 0.25

    def validate(self) -> None:
        super().validate()
        require(self.solver_iterations >= 1, "solver_iterations", "must be >= 1")
        require(self.ls_iterations >= 1, "ls_iterations", "must be >= 1")
        randomize.check_range("target_distance", self.target_distance, positive=True)
        weights = ("progress_weight", "energy_weight", "alive_bonus", "tilt_weight", "spin_weight")
        others = ("init_joint_noise", "action_noise", "obs_noise", "waypoint_radius")
        for name in (*weights, *others):
            require(getattr(self, name) >= 0, name, "must be >= 0")
        require(
            self.target_distance[0] > self.waypoint_radius,
            "target_distance",
            f"must start beyond waypoint_radius ({self.waypoint_radius} m)",
        )
        require(0 < self.min_height < self.init_height, "min_height", "must be in (0, init_height)")
        require(-1 <= self.min_upright < 1, "min_upright", "must be in [-1, 1)")


class WalkExtras(struct.PyTreeNode):
    """``HexapodWalk-v0``'s own state.

    Attributes:
      targets_reached: targets reached so far in the episode (int32).
    """

    targets_reached: jax.Array


class HexapodWalk(RobotTask, Env[WalkConfig]):
    """``HexapodWalk-v0``: walk the hexapod from target to target on the floor.

    * Observation (49), from the robot's readings: 18 joint angles (rad; legs lf, lm,
      lr, rf, rm, rr, each hip, femur, tibia: the encoders), 18 joint velocities (rad/s),
      body height (m; privileged ``torso_pos``), gravity direction in the body frame (3,
      from ``imu_quat``), body linear velocity in the body frame (3, m/s; privileged
      ``torso_vel``), body angular velocity in the body frame (3, rad/s, ``imu_gyro``),
      unit direction to the target in the body frame (3; the target is on the floor, the
      direction horizontal in world, from ``torso_pos`` and ``imu_quat``); with
      ``obs_noise`` > 0, plus Gaussian noise of std ``obs_noise * OBS_NOISE``.
    * Action: Box(18) in [-1, 1]: joint position targets, linear over each joint's range
      (with ``action_noise`` > 0, Gaussian noise of that std added, then clipped).
    * Reward: ``progress_weight * (d_prev - d) / 0.05 - energy_weight * sum|tau * qdot|
      - tilt_weight * (1 - up_z) - spin_weight * (w_roll^2 + w_pitch^2) + alive_bonus``
      with ``d`` the horizontal distance from the body to the target in force during the
      step (the progress term is the decrease of the distance per step expressed in m/s),
      ``up_z`` the vertical component of the body's up axis and ``w`` the body-frame
      angular velocity.
    * Waypoints: when a step ends with the body within ``waypoint_radius`` of the target,
      a new target is drawn at a distance in the params' ``target_range`` from the body,
      in a uniformly random direction; the next observation points at it. (A deployed
      walker's simulated robot keeps the target of its start: it stops there.)
      ``extras.targets_reached`` counts the arrivals, and ``info`` carries it as the
      metric ``targets_reached`` (with ``distance``, to the target in force during the
      step, ``progress`` and ``energy``).
    * Termination: height < ``min_height`` or the body's up axis z-component <
      ``min_upright`` (tilted more than ~45 degrees, on its side or flipped).
      Truncation: 1000 steps.
    * Start: body at 0.14 m with a random yaw, joints uniform in +-0.05 rad around the
      stance, at rest; target (a mocap marker) at a distance uniform in 1-3 m in a random
      direction.
    * Timing: 0.05 s per control step as 5 Euler substeps of 0.01 s.
    """

    cpu_physics = "c"  # physics="auto" on a CPU (benchmarks/RESULTS.md#engines)
    c_envs_per_device = None  # contact physics: one device's engine pool (NOTES)
    #: the servos' forces (the energy term); every other reading comes from qpos/qvel
    derived_fields: tuple[str, ...] | None = ("actuator_force",)
    robot: Hexapod

    metric_keys = ("distance", "progress", "energy", "targets_reached")
    #: the test battery's vmap-vs-single tolerance: the 6-iteration CG contact solve
    #: amplifies the batched program's last-bit differences.
    vmap_atol = 1e-2

    def __init__(self, config: WalkConfig | None = None) -> None:
        config = config or WalkConfig()
        self.robot = Hexapod()
        sim = self.robot.make_sim(
            config.timestep,
            config.substeps,
            edit=_solver_edit(config.solver_iterations, config.ls_iterations),
        )
        super().__init__(config, sim)
        self._torso = mujoco.mj_name2id(sim.mj_model, mujoco.mjtObj.mjOBJ_BODY, "torso")
        self._params = HexapodParams(
            model=self.robot.default_fields(sim),
            target_range=jnp.asarray(config.target_distance, jnp.float32),
        )

    observation_size = 49
    action_size = 18

    def _init(self, key: jax.Array, params: HexapodParams) -> tuple[mjx.Data, WalkExtras]:
        # one draw for all 21 numbers: each random call is a loop XLA compiles on its own
        # (on a CPU most of a first call's compile time is the PRNG's)
        u = jax.random.uniform(key, (21,))
        c = self.config
        yaw = math.pi * (2.0 * u[0] - 1.0)
        quat = jnp.stack([jnp.cos(yaw / 2), 0.0, 0.0, jnp.sin(yaw / 2)])
        n = c.init_joint_noise
        joints = n * (2.0 * u[1:19] - 1.0)
        qpos = self.robot.qpos(jnp.array([0.0, 0.0, c.init_height]), quat, joints)
        offset = _target_offset(u[19:21], params.target_range)
        target = jnp.concatenate([offset, jnp.array([0.01])])[None]
        data = self.sim.init_data(qpos=qpos, qvel=jnp.zeros(24), mocap_pos=target)
        return data, WalkExtras(targets_reached=jnp.zeros((), jnp.int32))

    def _act(
        self,
        key: jax.Array,
        data: mjx.Data,
        extras: WalkExtras,
        action: jax.Array,
        params: HexapodParams,
    ) -> tuple[mjx.Data, WalkExtras]:
        model = self.sim.model_with(params.model)
        if self.config.action_noise > 0:
            noise = self.config.action_noise * jax.random.normal(key, action.shape)
            action = jnp.clip(action + noise, -1.0, 1.0)
        data = self.sim.step(model, data, self.robot.command(action))
        if self.config.waypoint_radius > 0:
            data, extras = self.next_target(jax.random.fold_in(key, 1), data, extras, params)
        return data, extras

    def next_target(
        self, key: jax.Array, data: mjx.Data, extras: WalkExtras, params: HexapodParams
    ) -> tuple[mjx.Data, WalkExtras]:
        """``data`` with a new target drawn from ``key`` where the body is within
        ``waypoint_radius`` of the current one (else unchanged), and the arrival counted."""
        pos = self.robot.sense(data)["torso_pos"][:2]
        target = data.mocap_pos[0, :2]
        reached = jnp.linalg.norm(target - pos) < self.config.waypoint_radius
        new = pos + _target_offset(jax.random.uniform(key, (2,)), params.target_range)
        mocap = data.mocap_pos.at[0, :2].set(jnp.where(reached, new, target))
        count = extras.targets_reached + reached.astype(jnp.int32)
        return data.replace(mocap_pos=mocap), extras.replace(targets_reached=count)

    def task_state(self, data: mjx.Data, extras: WalkExtras) -> jax.Array:
        """The task's own input to :meth:`observation`: the target's world (x, y) (m)."""
        return data.mocap_pos[0, :2]

    def observation(self, readings: Readings, target: jax.Array) -> jax.Array:
        """The noiseless observation (the layout in the class docstring) of the robot's
        ``readings`` and the target's world (x, y)."""
        quat, pos = readings["imu_quat"], readings["torso_pos"]
        to_target = target - pos[:2]
        to_target = to_target / jnp.maximum(jnp.linalg.norm(to_target), 1e-6)
        direction = world_to_body(quat, jnp.concatenate([to_target, jnp.zeros(1)]))
        return jnp.concatenate(
            [
                self.robot.joint_pos(readings),
                self.robot.joint_vel(readings),
                pos[2:3],
                gravity_in_body(quat),
                readings["torso_vel"],
                readings["imu_gyro"],
                direction,
            ]
        )

    def _observe(
        self, key: jax.Array, data: mjx.Data, extras: WalkExtras, params: HexapodParams
    ) -> jax.Array:
        obs = self.observation(self.robot.sense(data), self.task_state(data, extras))
        if self.config.obs_noise > 0:
            obs = obs + self.config.obs_noise * OBS_NOISE * jax.random.normal(key, obs.shape)
        return obs

    def _reward(
        self,
        prev: mjx.Data,
        data: mjx.Data,
        action: jax.Array,
        extras: WalkExtras,
        params: HexapodParams,
    ) -> tuple[jax.Array, dict[str, jax.Array]]:
        c = self.config
        before, now = self.robot.sense(prev), self.robot.sense(data)
        target = prev.mocap_pos[0, :2]  # in force during the step (a waypoint may follow)
        d_prev = jnp.linalg.norm(target - before["torso_pos"][:2])
        dist = jnp.linalg.norm(target - now["torso_pos"][:2])
        progress = (d_prev - dist) / self.control_dt
        energy = jnp.sum(jnp.abs(data.actuator_force * self.robot.joint_vel(now)))
        spin = jnp.sum(jnp.square(now["imu_gyro"][:2]))  # body-frame roll and pitch rates
        reward = (
            c.progress_weight * progress
            - c.energy_weight * energy
            - c.tilt_weight * (1.0 - self.robot.upright(now))
            - c.spin_weight * spin
            + c.alive_bonus
        )
        metrics = {
            "distance": dist,
            "progress": progress,
            "energy": energy,
            "targets_reached": extras.targets_reached,
        }
        return reward, metrics

    def _terminated(self, data: mjx.Data, extras: WalkExtras, params: HexapodParams) -> jax.Array:
        """Fallen: the body below ``min_height`` or tilted past ``min_upright``."""
        c = self.config
        now = self.robot.sense(data)
        return (self.robot.height(now) < c.min_height) | (self.robot.upright(now) < c.min_upright)


# ------------------------------------------------------------------------ HexapodOneLeg-v0
@dataclasses.dataclass(frozen=True)
class OneLegConfig(HexapodRandomization):
    """``HexapodOneLeg-v0``.

    Attributes:
      episode_length: 100 steps of 0.05 s (5 s).
      target_fraction: the target posture's joint angles are drawn uniformly in
        (low, high) x each joint's half-range ((-1, 1) = anywhere the leg can reach).
      init_joint_noise: initial joint angles uniform in +- this (rad).
    """

    episode_length: int = 100
    target_fraction: Range = (-1.0, 1.0)
    init_joint_noise: float = 0.1

    def validate(self) -> None:
        super().validate()
        randomize.check_range("target_fraction", self.target_fraction, min_low=-1, max_high=1)
        require(self.init_joint_noise >= 0, "init_joint_noise", "must be >= 0")


class OneLegExtras(struct.PyTreeNode):
    """``HexapodOneLeg-v0``'s own state.

    Attributes:
      target_q: the target posture's joint angles (3, rad); the target is their foot tip.
    """

    target_q: jax.Array


class HexapodOneLeg(RobotTask, Env[OneLegConfig]):
    """``HexapodOneLeg-v0``: one hexapod leg on a fixed base reaches for a target.

    * Observation (9): the 3 joint angles (rad, the encoders), 3 joint velocities
      (rad/s), the target (3, m, in the hip's frame).
    * Action: Box(3) in [-1, 1]: joint position targets, linear over each joint's range.
    * Reward: ``-|tip - target|^2`` (m^2), the foot tip from exact forward kinematics.
    * Termination: none. Truncation: 100 steps.
    * Start: joints uniform in +-0.1 rad, at rest. Target: joint angles drawn uniformly
      in ``target_fraction`` x each joint's half-range, mapped through forward kinematics,
      so it is always reachable; ``extras`` (:class:`OneLegExtras`) keeps those angles.
    * Timing: 0.05 s per control step as 5 Euler substeps of 0.01 s; gravity on; no
      contacts or constraints.
    """

    cpu_physics = "c"  # physics="auto" on a CPU (benchmarks/RESULTS.md#engines)
    c_envs_per_device = None  # contact physics: one device's engine pool (NOTES)
    #: every reading comes from qpos/qvel
    derived_fields: tuple[str, ...] | None = ()
    robot: HexapodLeg

    metric_keys = ("distance",)

    def __init__(self, config: OneLegConfig | None = None) -> None:
        config = config or OneLegConfig()
        self.robot = HexapodLeg()
        super().__init__(config, self.robot.make_sim(config.timestep, config.substeps))
        self._params = HexapodParams(
            model=self.robot.default_fields(self.sim),
            target_range=jnp.asarray(config.target_fraction, jnp.float32),
        )

    observation_size = 9
    action_size = 3

    def _init(self, key: jax.Array, params: HexapodParams) -> tuple[mjx.Data, OneLegExtras]:
        u = jax.random.uniform(key, (6,))  # one draw: see HexapodWalk._init
        n = self.config.init_joint_noise
        qpos = n * (2.0 * u[:3] - 1.0)
        low, high = params.target_range[0], params.target_range[1]
        fraction = low + (high - low) * u[3:]
        target_q = fraction * JOINT_RANGE[:3]
        mocap = (leg_tip(target_q) + self.robot.hip)[None]
        data = self.sim.init_data(qpos=qpos, qvel=jnp.zeros(3), mocap_pos=mocap)
        return data, OneLegExtras(target_q=target_q)

    def target(self, data: mjx.Data) -> jax.Array:
        """The target in the hip's frame (m)."""
        return data.mocap_pos[0] - self.robot.hip

    def task_state(self, data: mjx.Data, extras: OneLegExtras) -> jax.Array:
        """The task's own input to :meth:`observation`: the target in the hip's frame."""
        return self.target(data)

    def _act(
        self,
        key: jax.Array,
        data: mjx.Data,
        extras: OneLegExtras,
        action: jax.Array,
        params: HexapodParams,
    ) -> tuple[mjx.Data, OneLegExtras]:
        model = self.sim.model_with(params.model)
        return self.sim.step(model, data, self.robot.command(action)), extras

    def observation(self, readings: Readings, target: jax.Array) -> jax.Array:
        """The observation (class docstring) of the encoders' ``readings`` and the target
        in the hip's frame."""
        return jnp.concatenate(
            [self.robot.joint_pos(readings), self.robot.joint_vel(readings), target]
        )

    def _reward(
        self,
        prev: mjx.Data,
        data: mjx.Data,
        action: jax.Array,
        extras: OneLegExtras,
        params: HexapodParams,
    ) -> tuple[jax.Array, dict[str, jax.Array]]:
        err = leg_tip(self.robot.joint_pos(self.robot.sense(data))) - self.target(data)
        sq = jnp.sum(err * err)
        return -sq, {"distance": jnp.sqrt(sq)}
