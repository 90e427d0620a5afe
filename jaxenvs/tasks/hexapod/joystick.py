"""``HexapodJoystick-v0``: drive the hexapod with a velocity command (forward and lateral
speed in the body frame, yaw rate), from what the robot measures.

The observation is :meth:`HexapodJoystick.observation` of the robot's non-privileged
readings (:meth:`~jaxenvs.robots.base.Robot.sense`: encoders and IMU) and the task's own
state (:meth:`HexapodJoystick.task_state`: the command and the last ``action_delay_max +
1`` actions), so a loop driving a real hexapod computes it from readings received over a
link with ``observation(readings, (command, actions))`` (:meth:`with_action_history` puts
the actions it sent into the task state). Body velocities, the world position and the
world yaw are privileged: the reward uses them, the policy does not see them.

For the gap between simulation and a robot driven over a link (``jaxenvs deploy``), the
config can delay each env's actions by 0 to ``action_delay_max`` control steps (a delay
drawn per env at reset), and offset each env's joint angle and gyro readings by constant
biases drawn at reset (``joint_bias``, ``gyro_bias``); the servos' strength (kp) is drawn
per env by ``gain_scale`` when params are randomised. All draws come from the hooks' keys,
so MJX and MuJoCo C physics see the same ones.

Physics as ``HexapodWalk-v0`` (:mod:`jaxenvs.tasks.hexapod.base`): the robot on its
scene, six foot-ground contact pairs, Euler with implicit damping, the config's contact
model (``cone``, ``solver`` and their iterations: elliptic, ``solver: auto``, by default).
"""

from __future__ import annotations

import dataclasses
import math
from typing import TYPE_CHECKING, ClassVar

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct

from jaxenvs.config import require
from jaxenvs.core import State
from jaxenvs.randomize import Range
from jaxenvs.robots.base import Readings, gravity_in_body
from jaxenvs.scenes import Ground
from jaxenvs.tasks import rewards
from jaxenvs.tasks.hexapod.base import HexapodConfig, HexapodTask

if TYPE_CHECKING:
    from mujoco import mjx

#: the observation noise at ``obs_noise=1`` of the 42 sensor entries: joint angles (rad),
#: joint velocities (rad/s), gravity direction, gyro (rad/s); the actions and the command
#: that follow them are known exactly (no noise)
OBS_NOISE = np.concatenate(
    [np.full(18, 0.01), np.full(18, 0.3), np.full(3, 0.02), np.full(3, 0.05)]
).astype(np.float32)
#: the number of sensor entries at the head of the observation
SENSOR_SIZE = 42


@dataclasses.dataclass(frozen=True)
class JoystickConfig(HexapodConfig):
    """``HexapodJoystick-v0`` (the fields it shares with the walker:
    :class:`~jaxenvs.tasks.hexapod.base.HexapodConfig`).

    Attributes:
      episode_length: 1000 steps of 0.05 s (50 s): ten commands per episode. Training
        costs the same at any length (batched envs reset on their own); a shorter one
        would spend more of the data on starts from rest.
      vx_range: forward speed command range (m/s, body frame).
      vy_range: lateral speed command range (m/s, body frame, positive to the left).
      yaw_range: yaw rate command range (rad/s, positive counter-clockwise from above).
      zero_probability: probability that a drawn command is zero (stand still).
      command_interval: the command is redrawn every this many control steps.
      lin_weight, lin_sigma: weight and width (m^2/s^2) of the linear tracking term
        ``exp(-|v_cmd - v|^2 / lin_sigma)``.
      yaw_weight, yaw_sigma: weight and width (rad^2/s^2) of the yaw-rate tracking term.
      vz_weight: weight of the squared vertical body speed (m^2/s^2).
      action_rate_weight: weight of the squared change of the action since the last step.
      push_probability: probability per control step of a push ...
      push_speed: ... which adds a horizontal velocity of this magnitude (m/s) in a
        uniformly random direction to the body.
      action_delay_max: each env applies the action of ``d`` control steps ago, ``d``
        drawn uniformly in 0..``action_delay_max`` at reset (0: no delay). The
        observation holds the last ``action_delay_max + 1`` actions.
      joint_bias: each env's joint angle readings are offset by constants drawn at reset
        uniformly in +- this (rad; 0: none), in the observation only (as ``obs_noise``).
      gyro_bias: ... and its gyro readings by constants uniform in +- this (rad/s).
      action_filter: a first-order low-pass on the servo targets: each step's targets are
        ``(1 - action_filter) * targets(applied action) + action_filter * targets of the
        step before`` (0: none; the targets start at the stance, 0).
    """

    vx_range: Range = (-0.4, 0.4)
    vy_range: Range = (-0.25, 0.25)
    yaw_range: Range = (-0.8, 0.8)
    zero_probability: float = 0.1
    command_interval: int = 100
    lin_weight: float = 1.5
    lin_sigma: float = 0.04
    yaw_weight: float = 1.0
    yaw_sigma: float = 0.1
    vz_weight: float = 1.0
    spin_weight: float = 0.02
    tilt_weight: float = 1.0
    action_rate_weight: float = 0.03
    alive_bonus: float = 0.25
    push_probability: float = 0.0
    push_speed: float = 0.0
    action_delay_max: int = 0
    joint_bias: float = 0.0
    gyro_bias: float = 0.0
    action_filter: float = 0.0

    nonnegative: ClassVar[tuple[str, ...]] = (
        *HexapodConfig.nonnegative,
        "lin_weight",
        "yaw_weight",
        "vz_weight",
        "action_rate_weight",
        "push_speed",
        "action_delay_max",
        "joint_bias",
        "gyro_bias",
    )

    def validate(self) -> None:
        super().validate()
        for name in ("vx_range", "vy_range", "yaw_range"):
            low, high = getattr(self, name)
            require(low <= high, name, "must be (low, high) with low <= high")
        require(0 <= self.zero_probability <= 1, "zero_probability", "must be in [0, 1]")
        require(0 <= self.push_probability <= 1, "push_probability", "must be in [0, 1]")
        require(self.command_interval >= 1, "command_interval", "must be >= 1")
        require(self.lin_sigma > 0, "lin_sigma", "must be > 0")
        require(self.yaw_sigma > 0, "yaw_sigma", "must be > 0")
        require(0 <= self.action_filter < 1, "action_filter", "must be in [0, 1)")


class JoystickParams(struct.PyTreeNode):
    """Randomisable physics: ``model``, the MJX model fields swapped in at every step."""

    model: dict[str, jax.Array]


class JoystickExtras(struct.PyTreeNode):
    """``HexapodJoystick-v0``'s own state.

    Attributes:
      command: (vx, vy, yaw rate) in m/s, m/s, rad/s.
      since: control steps since the command was drawn.
      actions: the last ``action_delay_max + 1`` actions (each 18; as the policy gave
        them, before any delay or action noise), the most recent first.
      prev_action: the action before ``actions[0]`` (18).
      delay: this env's action delay (control steps, int32), drawn at reset.
      bias: this env's sensor offsets (:data:`SENSOR_SIZE`; joint angles and gyro, zero
        elsewhere), drawn at reset.
    """

    command: jax.Array
    since: jax.Array
    actions: jax.Array
    prev_action: jax.Array
    delay: jax.Array
    bias: jax.Array


def heading(quat: jax.Array) -> jax.Array:
    """The yaw (rad) of the body's x axis projected on the floor, for orientation ``quat``
    (w x y z)."""
    w, x, y, z = quat[0], quat[1], quat[2], quat[3]
    return jnp.arctan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z))


def heading_velocity(
    pos0: jax.Array, quat0: jax.Array, pos1: jax.Array, quat1: jax.Array, dt: float
) -> jax.Array:
    """The body's mean velocity over a step of ``dt`` seconds from pose 0 to pose 1:
    (forward, lateral) in the frame of the body's heading at the step's middle (m/s), and
    the yaw rate (rad/s)."""
    yaw0, yaw1 = heading(quat0), heading(quat1)
    turn = jnp.arctan2(jnp.sin(yaw1 - yaw0), jnp.cos(yaw1 - yaw0))
    mid = yaw0 + 0.5 * turn
    d = (pos1[:2] - pos0[:2]) / dt
    c, s = jnp.cos(mid), jnp.sin(mid)
    return jnp.stack([c * d[0] + s * d[1], -s * d[0] + c * d[1], turn / dt])


def low_pass(x: jax.Array, previous: jax.Array, beta: float) -> jax.Array:
    """One step of the first-order filter ``action_filter`` names: ``(1 - beta) * x + beta
    * previous`` (the env's servo targets and a deploy loop's commands alike)."""
    return (1.0 - beta) * x + beta * previous


def sample_command(u: jax.Array, config: JoystickConfig) -> jax.Array:
    """A command from four uniforms in [0, 1): three place it in the config's ranges, the
    fourth makes it zero with probability ``zero_probability``."""
    low = jnp.asarray([config.vx_range[0], config.vy_range[0], config.yaw_range[0]])
    high = jnp.asarray([config.vx_range[1], config.vy_range[1], config.yaw_range[1]])
    command = low + (high - low) * u[:3]
    return jnp.where(u[3] < config.zero_probability, jnp.zeros(3), command)


class HexapodJoystick(HexapodTask[JoystickConfig]):
    """``HexapodJoystick-v0``: follow a velocity command.

    * Observation (``45 + 18 * (action_delay_max + 1)``: 63 without delay),
      :meth:`observation` of the robot's readings: 18 joint angles (rad; legs lf, lm, lr,
      rf, rm, rr, each hip, femur, tibia: the encoders), 18 joint velocities (rad/s, the
      encoders), gravity direction in the body frame (3, from the IMU's ``imu_quat``),
      body angular velocity in the body frame (3, rad/s, the IMU's ``imu_gyro``), the last
      ``action_delay_max + 1`` actions the policy gave (18 each, the most recent first),
      the command (3: vx, vy in m/s, yaw rate in rad/s). In the env the sensor entries
      also carry the env's constant biases (``joint_bias``, ``gyro_bias``) and, with
      ``obs_noise`` > 0, Gaussian noise of std ``obs_noise * OBS_NOISE``; the actions and
      the command are exact. Nothing privileged: no position, world yaw or linear velocity.
    * Action: Box(18) in [-1, 1]: joint position targets, linear over each joint's range.
      The env applies the action of ``d`` steps ago (``d`` the env's delay, uniform in
      0..``action_delay_max`` at reset; before the first ``d`` steps, zero actions);
      with ``action_noise`` > 0, Gaussian noise of that std is added to it, then clipped;
      with ``action_filter`` > 0, the servo targets are low-passed
      (:meth:`actuator_command`: what a deploy loop sends).
    * Command: (vx, vy, yaw rate) uniform in ``vx_range`` x ``vy_range`` x ``yaw_range``,
      all zero with probability ``zero_probability``; drawn at reset and redrawn every
      ``command_interval`` steps (5 s), from the reset's and the act hook's keys.
    * Velocity: the body's mean velocity over the control step in the frame of its
      heading (forward, lateral; m/s) and its yaw rate (rad/s), from the torso's world
      pose before and after the step (:func:`heading_velocity`; privileged).
    * Reward: ``lin_weight * exp(-|cmd_xy - v_xy|^2 / lin_sigma) + yaw_weight *
      exp(-(cmd_yaw - yaw_rate)^2 / yaw_sigma) - vz_weight * v_z^2 - spin_weight *
      (w_roll^2 + w_pitch^2) - tilt_weight * (1 - up_z) - action_rate_weight * |a -
      a_prev|^2 - energy_weight * sum|tau * qdot| + alive_bonus``; ``v_z`` and ``w`` from
      the body-frame velocimeter and gyro at the step's end.
    * Metrics: ``lin_error`` (|cmd_xy - v_xy|, m/s), ``yaw_error`` (|cmd_yaw - yaw rate|,
      rad/s), ``energy`` (W), the step's velocity ``vel_forward``, ``vel_lateral`` (m/s)
      and ``yaw_rate`` (rad/s), and the body's ``height`` (m) at its end: privileged
      (a critic may see them: PPO's ``critic_info``).
    * Termination: height < ``min_height`` or the up axis' z-component < ``min_upright``
      (as ``HexapodWalk-v0``). Truncation: ``episode_length`` steps.
    * Start: body at 0.14 m with a random yaw, joints uniform in +-0.05 rad around the
      stance, at rest; past actions zero; the delay and the sensor biases drawn (from
      the reset key, only where the config enables them).
    * Pushes: with probability ``push_probability`` per step, a horizontal velocity of
      ``push_speed`` in a random direction is added to the body before the step.
    * Timing: 0.05 s per control step as 5 Euler substeps of 0.01 s.
    """

    metric_keys = (
        "lin_error",
        "yaw_error",
        "energy",
        "vel_forward",
        "vel_lateral",
        "yaw_rate",
        "height",
    )
    observation_size = 63  # the size without delay; an instance has its config's
    #: the config fields a deploy loop depends on: the observation's layout and the
    #: commands' filter (an exported policy's metadata carries them: ``jaxenvs deploy``
    #: builds the task with them)
    deploy_fields: tuple[str, ...] = ("action_delay_max", "action_filter")

    def __init__(self, config: JoystickConfig | None = None, ground: Ground | None = None) -> None:
        config = config or JoystickConfig()
        super().__init__(config, ground)
        self._params = JoystickParams(model=self.robot.default_fields(self.sim))
        #: the number of past actions in the observation (and the delay buffer's length)
        self.action_history = config.action_delay_max + 1
        self.observation_size = SENSOR_SIZE + 18 * self.action_history + 3

    def _init(self, key: jax.Array, params: JoystickParams) -> tuple[mjx.Data, JoystickExtras]:
        u = jax.random.uniform(key, (23,))  # one draw: see HexapodWalk._init
        c = self.config
        data = self.sim.init_data(qpos=self.spawn(u[:19]), qvel=jnp.zeros(24))
        extras = JoystickExtras(
            command=sample_command(u[19:23], c),
            since=jnp.zeros((), jnp.int32),
            actions=jnp.zeros((self.action_history, 18)),
            prev_action=jnp.zeros(18),
            delay=jnp.zeros((), jnp.int32),
            bias=jnp.zeros(SENSOR_SIZE),
        )
        biased = c.joint_bias > 0 or c.gyro_bias > 0
        if c.action_delay_max == 0 and not biased:
            return data, extras
        # the gap's draws from a key of their own, so that the draws above are those of a
        # config without them
        gap = jax.random.uniform(jax.random.fold_in(key, 1), (22,))
        if c.action_delay_max > 0:
            delay = jnp.floor(gap[0] * (c.action_delay_max + 1)).astype(jnp.int32)
            extras = extras.replace(delay=jnp.minimum(delay, c.action_delay_max))
        if biased:
            joint = c.joint_bias * (2.0 * gap[1:19] - 1.0)
            gyro = c.gyro_bias * (2.0 * gap[19:22] - 1.0)
            extras = extras.replace(bias=jnp.concatenate([joint, jnp.zeros(21), gyro]))
        return data, extras

    def _act(
        self,
        key: jax.Array,
        data: mjx.Data,
        extras: JoystickExtras,
        action: jax.Array,
        params: JoystickParams,
    ) -> tuple[mjx.Data, JoystickExtras]:
        c = self.config
        u = jax.random.uniform(key, (7,))  # command (4), push (3)
        actions = jnp.concatenate([action[None], extras.actions[:-1]])
        applied = action
        if c.action_delay_max > 0:  # the action of `delay` steps ago
            applied = jnp.take(actions, extras.delay, axis=0)
        if c.action_noise > 0:
            noise = c.action_noise * jax.random.normal(jax.random.fold_in(key, 1), action.shape)
            applied = jnp.clip(applied + noise, -1.0, 1.0)
        if c.push_probability > 0 and c.push_speed > 0:
            angle = 2.0 * math.pi * u[5]
            kick = c.push_speed * jnp.stack([jnp.cos(angle), jnp.sin(angle)])
            kick = jnp.where(u[4] < c.push_probability, kick, jnp.zeros(2))
            data = data.replace(qvel=data.qvel.at[:2].add(kick))
        targets = self.robot.command(applied)
        if c.action_filter > 0:  # data.ctrl: the targets of the step before
            # (the command map is linear in the action and the weights sum to 1: this is
            # actuator_command's filter mapped through the command map)
            targets = low_pass(targets, data.ctrl, c.action_filter)
        data = self.sim.step(self.sim.model_with(params.model), data, targets)
        since = extras.since + 1
        redraw = since >= c.command_interval
        extras = extras.replace(
            command=jnp.where(redraw, sample_command(u[:4], c), extras.command),
            since=jnp.where(redraw, 0, since),
            actions=actions,
            prev_action=extras.actions[0],
        )
        return data, extras

    def actuator_command(self, action: jax.Array, previous: jax.Array) -> jax.Array:
        """The action to send: ``(1 - action_filter) * action + action_filter *
        previous`` (the policy's ``action`` itself without a filter). The filter is linear
        with weights summing to 1, and the command map is linear, so the env's servo
        targets (filtered in :meth:`_act` from ``data.ctrl``) are the command map of this
        sequence of sent actions, shifted by the env's action delay."""
        beta = self.config.action_filter
        action = self.actuator_action(action)
        if beta == 0:
            return action
        return low_pass(action, jnp.asarray(previous, jnp.float32), beta)

    def task_state(self, data: mjx.Data, extras: JoystickExtras) -> tuple[jax.Array, ...]:
        """The task's own input to :meth:`observation`: (command (3), the last
        ``action_delay_max + 1`` actions (``(action_delay_max + 1, 18)``, the most recent
        first))."""
        del data
        return extras.command, extras.actions

    def observation(self, readings: Readings, task: tuple[jax.Array, ...]) -> jax.Array:
        """The noiseless, unbiased observation (the layout in the class docstring) of the
        robot's ``readings`` (only its non-privileged sensors are read) and ``(command,
        actions)``."""
        command, actions = task
        return jnp.concatenate(
            [
                self.robot.joint_pos(readings),
                self.robot.joint_vel(readings),
                gravity_in_body(readings["imu_quat"]),
                readings["imu_gyro"],
                jnp.reshape(actions, (18 * self.action_history,)),
                command,
            ]
        )

    def _observe(
        self, key: jax.Array, data: mjx.Data, extras: JoystickExtras, params: JoystickParams
    ) -> jax.Array:
        c = self.config
        obs = self.observation(self.robot.sense(data), self.task_state(data, extras))
        exact = jnp.zeros(obs.shape[0] - SENSOR_SIZE)  # the actions and the command
        if c.joint_bias > 0 or c.gyro_bias > 0:
            obs = obs + jnp.concatenate([extras.bias, exact])
        if c.obs_noise > 0:
            std = c.obs_noise * jnp.concatenate([jnp.asarray(OBS_NOISE), exact])
            obs = obs + std * jax.random.normal(key, obs.shape)
        return obs

    #: the shape of the task's input in a deploy loop (``jaxenvs deploy --command``): the
    #: command (vx, vy, yaw rate)
    task_input_shape = (3,)

    def with_task_input(
        self, task: tuple[jax.Array, ...], command: jax.Array
    ) -> tuple[jax.Array, ...]:
        """The task state ``(command, actions)`` with ``command`` in force (a deploy loop's
        task input)."""
        return jnp.asarray(command, jnp.float32), task[1]

    def with_action_history(
        self, task: tuple[jax.Array, ...], actions: jax.Array
    ) -> tuple[jax.Array, ...]:
        """The task state ``(command, actions)`` with ``actions`` (``(action_history,
        18)``, the most recent first: the last actions a deploy loop applied, before
        :meth:`actuator_command`'s filter)."""
        return task[0], jnp.asarray(actions, jnp.float32)

    def tracking_errors(
        self, prev: mjx.Data, data: mjx.Data, task: tuple[jax.Array, ...]
    ) -> dict[str, jax.Array]:
        """``lin`` (|cmd_xy - v_xy|, m/s) and ``yaw`` (|cmd_yaw - yaw rate|, rad/s) of the
        step ``prev -> data`` (one control period apart) under the command of ``task``: the
        task's ``lin_error`` and ``yaw_error`` metrics."""
        vel = self.velocity(prev, data)
        command = task[0]
        return {
            "lin": jnp.sqrt(jnp.sum(jnp.square(command[:2] - vel[:2]))),
            "yaw": jnp.abs(command[2] - vel[2]),
        }

    @property
    def command_range(self) -> tuple[np.ndarray, np.ndarray]:
        """The lowest and highest command (vx, vy, yaw rate) of the config's ranges."""
        c = self.config
        low = np.array([c.vx_range[0], c.vy_range[0], c.yaw_range[0]], np.float32)
        high = np.array([c.vx_range[1], c.vy_range[1], c.yaw_range[1]], np.float32)
        return low, high

    def with_command(self, state: State, command: jax.Array) -> State:
        """``state`` with ``command`` (vx, vy, yaw rate) as the current command, in its
        extras and its observation, and the redraw schedule restarted: a driver that sets
        it before every step (``jaxenvs view``'s keys) overrides the drawn commands."""
        command = jnp.asarray(command, jnp.float32)
        extras = state.extras.replace(command=command, since=jnp.zeros_like(state.extras.since))
        return state.replace(extras=extras, obs=state.obs.at[..., -3:].set(command))

    def velocity(self, prev: mjx.Data, data: mjx.Data) -> jax.Array:
        """(forward, lateral, yaw rate) of the step ``prev -> data`` (:func:`heading_velocity`)."""
        return heading_velocity(
            prev.qpos[:3], prev.qpos[3:7], data.qpos[:3], data.qpos[3:7], self.control_dt
        )

    def _reward(
        self,
        prev: mjx.Data,
        data: mjx.Data,
        action: jax.Array,
        extras: JoystickExtras,
        params: JoystickParams,
    ) -> tuple[jax.Array, dict[str, jax.Array]]:
        c = self.config
        now = self.robot.sense(data)
        vel = self.velocity(prev, data)
        lin_sq = jnp.sum(jnp.square(extras.command[:2] - vel[:2]))
        yaw_sq = jnp.square(extras.command[2] - vel[2])
        energy = self.energy(data, now)
        spin = rewards.roll_pitch_rate_sq(now["imu_gyro"])
        vz = now["torso_vel"][2]
        rate = jnp.sum(jnp.square(extras.actions[0] - extras.prev_action))
        up_z = self.robot.upright(now)
        reward = (
            c.lin_weight * jnp.exp(-lin_sq / c.lin_sigma)
            + c.yaw_weight * jnp.exp(-yaw_sq / c.yaw_sigma)
            - c.vz_weight * vz * vz
            - c.spin_weight * spin
            - c.tilt_weight * (1.0 - up_z)
            - c.action_rate_weight * rate
            - c.energy_weight * energy
            + c.alive_bonus
        )
        metrics = {
            "lin_error": jnp.sqrt(lin_sq),
            "yaw_error": jnp.sqrt(yaw_sq),
            "energy": energy,
            "vel_forward": vel[0],
            "vel_lateral": vel[1],
            "yaw_rate": vel[2],
            "height": self.height_above_ground(data.qpos[:3]),
        }
        return reward, metrics
