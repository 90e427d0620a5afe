"""``HexapodWalk-v0``: walk the hexapod from target to target (a new one drawn on
arrival); falls end the episode. The robot, the scene and what the hexapod tasks share:
:mod:`jaxenvs.tasks.hexapod.base`."""

from __future__ import annotations

import dataclasses
import math
from typing import TYPE_CHECKING, ClassVar

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct

from jaxenvs import randomize
from jaxenvs.config import require
from jaxenvs.randomize import Range
from jaxenvs.robots.base import Readings, gravity_in_body, world_to_body
from jaxenvs.scenes import Ground
from jaxenvs.tasks import rewards
from jaxenvs.tasks.hexapod.base import TARGET, HexapodConfig, HexapodParams, HexapodTask

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


# -------------------------------------------------------------------------- HexapodWalk-v0
def target_offset(u: jax.Array, target_range: jax.Array) -> jax.Array:
    """A target's horizontal offset (2,) from where it is drawn (m): at a distance in
    ``target_range``, in a uniformly random direction, from two uniforms ``u`` in [0, 1)."""
    low, high = target_range[0], target_range[1]
    dist = low + (high - low) * u[0]
    angle = math.pi * (2.0 * u[1] - 1.0)
    return jnp.stack([dist * jnp.cos(angle), dist * jnp.sin(angle)])


@dataclasses.dataclass(frozen=True)
class WalkConfig(HexapodConfig):
    """``HexapodWalk-v0`` (the fields it shares with the joystick:
    :class:`~jaxenvs.tasks.hexapod.base.HexapodConfig`).

    Attributes:
      target_distance: each target (at reset, and each waypoint) is drawn at a distance
        from the body uniform in this range (m), in a uniformly random direction; its low
        end must exceed ``waypoint_radius``, so that a new target is never reached at once.
      progress_weight: weight of the progress term (metres per second toward the target).
      waypoint_radius: a target counts as reached when the body centre comes within this
        horizontal distance of it (m; about a body length), and a new target is drawn
        (waypoints); 0: one target per episode, never replaced.
    """

    target_distance: Range = (1.0, 3.0)
    progress_weight: float = 1.0
    waypoint_radius: float = 0.25

    nonnegative: ClassVar[tuple[str, ...]] = (
        *HexapodConfig.nonnegative,
        "progress_weight",
        "waypoint_radius",
    )

    def validate(self) -> None:
        super().validate()
        randomize.check_range("target_distance", self.target_distance, positive=True)
        require(
            self.target_distance[0] > self.waypoint_radius,
            "target_distance",
            f"must start beyond waypoint_radius ({self.waypoint_radius} m)",
        )


class WalkExtras(struct.PyTreeNode):
    """``HexapodWalk-v0``'s own state.

    Attributes:
      targets_reached: targets reached so far in the episode (int32).
    """

    targets_reached: jax.Array


class HexapodWalk(HexapodTask[WalkConfig]):
    """``HexapodWalk-v0``: walk the hexapod from target to target on the floor.

    * Observation (49), from the robot's readings: 18 joint angles (rad; legs lf, lm,
      lr, rf, rm, rr, each hip, femur, tibia: the encoders), 18 joint velocities (rad/s),
      body height (m, above the ground under the body: :meth:`height_above_ground`;
      privileged ``torso_pos``), gravity direction in the body frame (3, from
      ``imu_quat``), body linear velocity in the body frame (3, m/s; privileged
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

    metric_keys = ("distance", "progress", "energy", "targets_reached")

    def __init__(self, config: WalkConfig | None = None, ground: Ground | None = None) -> None:
        config = config or WalkConfig()
        super().__init__(config, ground, markers=(TARGET,))
        self._params = HexapodParams(
            model=self.robot.default_fields(self.sim),
            target_range=jnp.asarray(config.target_distance, jnp.float32),
        )

    observation_size = 49

    def _init(self, key: jax.Array, params: HexapodParams) -> tuple[mjx.Data, WalkExtras]:
        # one draw for all 21 numbers: each random call is a loop XLA compiles on its own
        # (on a CPU most of a first call's compile time is the PRNG's)
        u = jax.random.uniform(key, (21,))
        qpos = self.spawn(u[:19])
        offset = target_offset(u[19:21], params.target_range)
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
        """``data`` with a new target (:meth:`draw_target`, placed by :meth:`place_target`)
        where the body is within ``waypoint_radius`` of the current one (else unchanged),
        and the arrival counted."""
        pos = self.robot.sense(data)["torso_pos"][:2]
        reached = jnp.linalg.norm(data.mocap_pos[0, :2] - pos) < self.config.waypoint_radius
        new = self.place_target(data.mocap_pos, self.draw_target(key, pos, extras, params))
        mocap = jnp.where(reached, new, data.mocap_pos)
        count = extras.targets_reached + reached.astype(jnp.int32)
        return data.replace(mocap_pos=mocap), extras.replace(targets_reached=count)

    def draw_target(
        self, key: jax.Array, pos: jax.Array, extras: WalkExtras, params: HexapodParams
    ) -> jax.Array:
        """A new target's world (x, y), drawn from ``key`` for a body at ``pos`` (x, y):
        at a distance in ``target_range`` from the body, in a uniformly random direction."""
        del extras
        return pos + target_offset(jax.random.uniform(key, (2,)), params.target_range)

    def place_target(self, mocap_pos: jax.Array, target: jax.Array) -> jax.Array:
        """``mocap_pos`` with the target marker at world (x, y) ``target`` (its height
        kept)."""
        return mocap_pos.at[0, :2].set(target)

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
                self.height_above_ground(pos)[None],
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
        energy = self.energy(data, now)
        spin = rewards.roll_pitch_rate_sq(now["imu_gyro"])
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
