"""Cartpole tasks: four tasks over one robot (:mod:`jaxenvs.robots.cartpole`).

The robot (cart, pole, motor, encoders, randomisable fields) is described in
:mod:`jaxenvs.robots.cartpole`: ``ctrl`` in [-1, 1] times ``actuator_gear`` (10 N by
default) is the cart force; no contacts, no constraints, Euler integration: episodes end on
bounds, not on limits. Each task's observation is :meth:`observation` of the robot's
encoder readings (and, where it needs one, the task's own state).

=====================  ==============================================================
``CartPole-v0``         classic control (Gymnasium CartPole-v1 semantics)
``CartpoleStayUp-v0``   the ROS course's stay-up task with velocity-increment commands
``CartpoleBalance-v0``  DM-Control-style balance, continuous force, dense reward
``CartpoleSwingup-v0``  the same from hanging down
=====================  ==============================================================

Params (the randomisable physics, a pytree passed to reset/step): ``model`` holds MJX
model fields ``body_mass``, ``body_inertia``, ``dof_damping`` and ``actuator_gear``.
``sample_params`` (used by ``make(..., num_envs=N, randomize=True)`` at each env's every
reset) draws them from every cartpole config's randomisation ranges
(:class:`~jaxenvs.robots.cartpole.CartpoleRanges`): cart and pole mass and inertia scaled
together by ``mass_scale`` (one factor per body), slider and hinge damping plus an offset
uniform in ``damping_range`` (their default is 0), the motor's gear scaled by
``gain_scale``. No friction: the cartpole has no contacts.
"""

from __future__ import annotations

import dataclasses
import math
from typing import TYPE_CHECKING, Any

import jax
import jax.numpy as jnp
from flax import struct

from jaxenvs.config import require
from jaxenvs.core import Env, NoExtras, TaskConfig
from jaxenvs.robots.base import Readings, RobotTask
from jaxenvs.robots.cartpole import Cartpole, CartpoleRanges
from jaxenvs.tasks.rewards import tolerance

if TYPE_CHECKING:
    from mujoco import mjx


class CartpoleParams(struct.PyTreeNode):
    """Randomisable physics: MJX model fields swapped in at every step."""

    model: dict[str, jax.Array]


def _default_params(robot: Cartpole, sim: Any, force: float | None = None) -> CartpoleParams:
    fields = robot.default_fields(sim)
    if force is not None:
        fields["actuator_gear"] = fields["actuator_gear"].at[0, 0].set(force)
    return CartpoleParams(model=fields)


@dataclasses.dataclass(frozen=True)
class CartpoleRandomization(CartpoleRanges, TaskConfig):
    """Domain-randomisation ranges shared by every cartpole config (used only with
    ``randomize=True``): the robot's :class:`~jaxenvs.robots.cartpole.CartpoleRanges`
    (``mass_scale``, ``damping_range``, ``gain_scale``) as config fields."""


class _CartpoleTask(RobotTask):
    """What the four cartpole tasks share: the robot, params, the engine choice."""

    #: physics="auto" on a CPU: C at every batch size (with the engine stepping on XLA's
    #: thread pool, C led MJX at 16 to 16,384 envs on 2 and on 16 cores;
    #: benchmarks/RESULTS.md, "physics='auto' on a CPU")
    #: every reading comes from qpos/qvel: the C engine writes no derived field
    derived_fields: tuple[str, ...] | None = ()
    robot: Cartpole


# --------------------------------------------------------------------------- CartPole-v0
@dataclasses.dataclass(frozen=True)
class CartPoleConfig(CartpoleRandomization):
    """Classic CartPole.

    Attributes:
      episode_length: truncation (500, as CartPole-v1).
      timestep, substeps: physics; control period = 0.02 s.
      force: push magnitude in newtons.
      theta_threshold: terminate when |pole angle| exceeds this (rad, 12 degrees).
      x_threshold: terminate when |cart position| exceeds this (m).
      init_range: initial state drawn uniformly in +-init_range per variable.
    """

    episode_length: int = 500
    timestep: float = 0.02
    substeps: int = 1
    force: float = 10.0
    theta_threshold: float = 12 * 2 * math.pi / 360
    x_threshold: float = 2.4
    init_range: float = 0.05

    def validate(self) -> None:
        super().validate()
        require(self.force > 0, "force", "must be positive")
        require(self.theta_threshold > 0, "theta_threshold", "must be positive")
        require(self.x_threshold > 0, "x_threshold", "must be positive")
        require(self.init_range >= 0, "init_range", "must be >= 0")


class CartPole(_CartpoleTask, Env[CartPoleConfig]):
    """``CartPole-v0``: keep the pole up by pushing the cart left or right.

    * Observation (4): cart position, cart velocity, pole angle, pole angular velocity.
    * Action: Discrete(2): 0 pushes left, 1 pushes right, with ``force`` newtons.
    * Reward: +1 per step, including the terminating one.
    * Termination: |angle| > 12 degrees or |position| > 2.4 m. Truncation: 500 steps.
    * Start: every state variable uniform in +-0.05.
    * Timing: 0.02 s per step (MJX semi-implicit Euler, one 0.02 s substep).
    """

    scan_unroll = 5

    def __init__(self, config: CartPoleConfig | None = None) -> None:
        config = config or CartPoleConfig()
        self.robot = Cartpole()
        super().__init__(config, self.robot.make_sim(config.timestep, config.substeps))
        self._params = _default_params(self.robot, self.sim, config.force)

    observation_size = 4
    action_size = 2
    discrete = True

    def _init(self, key: jax.Array, params: CartpoleParams) -> tuple[mjx.Data, NoExtras]:
        r = self.config.init_range
        s = jax.random.uniform(key, (4,), minval=-r, maxval=r)
        data = self.sim.init_data(qpos=s[jnp.array([0, 2])], qvel=s[jnp.array([1, 3])])
        return data, NoExtras()

    def _act(
        self,
        key: jax.Array,
        data: mjx.Data,
        extras: NoExtras,
        action: jax.Array,
        params: CartpoleParams,
    ) -> tuple[mjx.Data, NoExtras]:
        ctrl = self.robot.command(self.actuator_action(action))
        return self.sim.step(self.sim.model_with(params.model), data, ctrl), extras

    def actuator_action(self, action: jax.Array) -> jax.Array:
        """Action 1 pushes right (+1), any other left (-1)."""
        return jnp.where(action == 1, 1.0, -1.0)[None]

    def observation(self, readings: Readings, task: NoExtras) -> jax.Array:
        """Cart position, cart velocity, pole angle, pole angular velocity."""
        return self.robot.state(readings)

    def _reward(
        self,
        prev: mjx.Data,
        data: mjx.Data,
        action: jax.Array,
        extras: NoExtras,
        params: CartpoleParams,
    ) -> tuple[jax.Array, dict[str, jax.Array]]:
        return jnp.ones((), jnp.float32), {}

    def _terminated(self, data: mjx.Data, extras: NoExtras, params: CartpoleParams) -> jax.Array:
        c = self.config
        readings = self.robot.sense(data)
        x, theta = self.robot.cart(readings)[0], self.robot.pole(readings)[0]
        return (jnp.abs(x) > c.x_threshold) | (jnp.abs(theta) > c.theta_threshold)


# --------------------------------------------------------------------- CartpoleStayUp-v0
@dataclasses.dataclass(frozen=True)
class StayUpConfig(CartpoleRandomization):
    """The ROS course's cartpole stay-up task (key names follow its parameter file).

    Attributes:
      n_actions: 2 (left, right) or 4 (adds big left, big right = 10 x pos_step).
      pos_step: velocity increment of one action (m/s).
      running_step: seconds each command is held (the control period).
      timestep: physics timestep; ``running_step`` must be a multiple of it.
      max_base_velocity: commanded cart velocity is clipped to +-this (m/s).
      min_pole_angle, max_pole_angle: pole angle bounds (rad); outside ends the episode.
      min_base_pose_x, max_base_pose_x: cart position bounds (m); outside ends it too.
      init_pos: cart start position (m).
      init_noise: uniform noise on the initial pole angle and both velocities.
      velocity_gain: gain of the cart's velocity servo (N per m/s).
      max_force: the servo's force limit (N).
    """

    episode_length: int = 1000
    n_actions: int = 4
    pos_step: float = 0.016
    running_step: float = 0.04
    timestep: float = 0.01
    max_base_velocity: float = 50.0
    min_pole_angle: float = -0.7
    max_pole_angle: float = 0.7
    min_base_pose_x: float = -2.5
    max_base_pose_x: float = 2.5
    init_pos: float = 0.0
    init_noise: float = 0.05
    velocity_gain: float = 50.0
    max_force: float = 100.0

    @property
    def substeps(self) -> int:
        return max(1, round(self.running_step / self.timestep))

    def validate(self) -> None:
        super().validate()
        require(self.n_actions in (2, 4), "n_actions", "must be 2 or 4")
        require(self.pos_step > 0, "pos_step", "must be positive")
        require(self.running_step > 0, "running_step", "must be positive")
        require(
            abs(self.substeps * self.timestep - self.running_step) < 1e-9,
            "running_step",
            f"must be a multiple of timestep ({self.timestep})",
        )
        require(self.max_base_velocity > 0, "max_base_velocity", "must be positive")
        require(self.min_pole_angle < self.max_pole_angle, "max_pole_angle", "must exceed min")
        require(self.min_base_pose_x < self.max_base_pose_x, "max_base_pose_x", "must exceed min")
        require(
            self.min_base_pose_x < self.init_pos < self.max_base_pose_x,
            "init_pos",
            "must lie inside the base bounds",
        )
        require(self.init_noise >= 0, "init_noise", "must be >= 0")
        require(self.velocity_gain > 0, "velocity_gain", "must be positive")
        require(self.max_force > 0, "max_force", "must be positive")


class StayUpExtras(struct.PyTreeNode):
    """``CartpoleStayUp-v0``'s own state.

    Attributes:
      command: the commanded cart velocity (m/s), float32 scalar.
    """

    command: jax.Array


class CartpoleStayUp(_CartpoleTask, Env[StayUpConfig]):
    """``CartpoleStayUp-v0``: keep the pole up by nudging the cart's commanded velocity.

    * Observation (4): cart position, cart velocity, pole angle, pole angular velocity.
    * Action: Discrete(n_actions). 0: command -= pos_step; 1: += pos_step; with 4 actions
      also 2: -= 10 pos_step; 3: += 10 pos_step. The command (clipped to
      +-max_base_velocity) is held for ``running_step`` s and tracked by a velocity servo
      (force = velocity_gain x error, limited to max_force) running at the physics rate,
      like the ROS joint velocity controller the course used.
    * Reward: +1 per step.
    * Termination: pole angle outside [min_pole_angle, max_pole_angle] or cart position
      outside [min_base_pose_x, max_base_pose_x]. Truncation: ``episode_length`` (nsteps).
    * Start: cart at ``init_pos``, pole angle and velocities uniform in +-init_noise,
      commanded velocity 0.
    * Timing: 0.01 s physics steps, 4 per control step (running_step 0.04 s).

    ``extras`` (:class:`StayUpExtras`) holds the commanded cart velocity.
    """

    metric_keys = ("command",)

    def __init__(self, config: StayUpConfig | None = None) -> None:
        config = config or StayUpConfig()
        self.robot = Cartpole()
        super().__init__(config, self.robot.make_sim(config.timestep, config.substeps))
        self._params = _default_params(self.robot, self.sim, config.max_force)
        steps = [-1.0, 1.0, -10.0, 10.0][: config.n_actions]
        self._increments = jnp.asarray(steps, jnp.float32) * config.pos_step

    observation_size = 4

    @property
    def action_size(self) -> int:
        return self.config.n_actions

    discrete = True

    def _init(self, key: jax.Array, params: CartpoleParams) -> tuple[mjx.Data, StayUpExtras]:
        n = self.config.init_noise
        noise = jax.random.uniform(key, (3,), minval=-n, maxval=n)
        qpos = jnp.stack([jnp.asarray(self.config.init_pos, jnp.float32), noise[0]])
        data = self.sim.init_data(qpos=qpos, qvel=noise[1:])
        return data, StayUpExtras(command=jnp.zeros((), jnp.float32))

    def _act(
        self,
        key: jax.Array,
        data: mjx.Data,
        extras: StayUpExtras,
        action: jax.Array,
        params: CartpoleParams,
    ) -> tuple[mjx.Data, StayUpExtras]:
        c = self.config
        command = jnp.clip(
            extras.command + self._increments[action], -c.max_base_velocity, c.max_base_velocity
        )

        def servo(d: mjx.Data) -> jax.Array:
            _, velocity = self.robot.cart(self.robot.sense(d))
            force = c.velocity_gain * (command - velocity)
            return self.robot.command(jnp.clip(force / c.max_force, -1.0, 1.0)[None])

        model = self.sim.model_with(params.model)
        return self.sim.step_controlled(model, data, servo), StayUpExtras(command=command)

    def observation(self, readings: Readings, task: StayUpExtras) -> jax.Array:
        """Cart position, cart velocity, pole angle, pole angular velocity (the commanded
        velocity is not observed)."""
        return self.robot.state(readings)

    def _reward(
        self,
        prev: mjx.Data,
        data: mjx.Data,
        action: jax.Array,
        extras: StayUpExtras,
        params: CartpoleParams,
    ) -> tuple[jax.Array, dict[str, jax.Array]]:
        return jnp.ones((), jnp.float32), {"command": extras.command}

    def _terminated(
        self, data: mjx.Data, extras: StayUpExtras, params: CartpoleParams
    ) -> jax.Array:
        c = self.config
        readings = self.robot.sense(data)
        x, theta = self.robot.cart(readings)[0], self.robot.pole(readings)[0]
        return (
            (theta < c.min_pole_angle)
            | (theta > c.max_pole_angle)
            | (x < c.min_base_pose_x)
            | (x > c.max_base_pose_x)
        )


# ------------------------------------------------------ CartpoleBalance / CartpoleSwingup
@dataclasses.dataclass(frozen=True)
class BalanceConfig(CartpoleRandomization):
    """DM-Control-style cartpole balance / swing-up.

    Attributes:
      swing_up: start hanging down (swing-up) instead of near upright (balance).
      episode_length: 1000 steps of 0.01 s (10 s).
      timestep, substeps: physics; control period 0.01 s.
      cart_limit: |cart position| beyond this ends the episode (the rail's end, m).
    """

    swing_up: bool = False
    episode_length: int = 1000
    timestep: float = 0.01
    substeps: int = 1
    cart_limit: float = 1.8

    def validate(self) -> None:
        super().validate()
        require(self.cart_limit > 0, "cart_limit", "must be positive")


class CartpoleBalance(_CartpoleTask, Env[BalanceConfig]):
    """``CartpoleBalance-v0`` / ``CartpoleSwingup-v0`` (``swing_up=True``).

    * Observation (5): cart position, cos and sin of the pole angle, cart velocity, pole
      angular velocity.
    * Action: Box(1) in [-1, 1], force = 10 N x action.
    * Reward in [0, 1] per step: upright x centred x small control x small velocity, with
      upright = (cos + 1) / 2, centred = (1 + tol(x, margin 2)) / 2,
      small control = (4 + tol_quadratic(a, margin 1)) / 5 and
      small velocity = (1 + tol(angular velocity, margin 5)) / 2 (DM Control's terms).
    * Termination: |cart position| > cart_limit. Truncation: 1000 steps.
    * Start (balance): cart uniform in +-0.1 m, pole uniform in +-0.034 rad;
      (swing-up): cart and pole ~ 0.01 N(0, 1) around hanging down (angle pi);
      velocities ~ 0.01 N(0, 1).
    * Timing: 0.01 s per step, one Euler substep.
    """

    scan_unroll = 5

    def __init__(self, config: BalanceConfig | None = None) -> None:
        config = config or BalanceConfig()
        self.robot = Cartpole()
        super().__init__(config, self.robot.make_sim(config.timestep, config.substeps))
        self._params = _default_params(self.robot, self.sim)

    observation_size = 5
    action_size = 1

    def _init(self, key: jax.Array, params: CartpoleParams) -> tuple[mjx.Data, NoExtras]:
        pos_key, vel_key = jax.random.split(key)
        if self.config.swing_up:
            qpos = 0.01 * jax.random.normal(pos_key, (2,)) + jnp.array([0.0, jnp.pi])
        else:
            qpos = jax.random.uniform(pos_key, (2,), minval=-1.0, maxval=1.0)
            qpos = qpos * jnp.array([0.1, 0.034])
        qvel = 0.01 * jax.random.normal(vel_key, (2,))
        return self.sim.init_data(qpos=qpos, qvel=qvel), NoExtras()

    def _act(
        self,
        key: jax.Array,
        data: mjx.Data,
        extras: NoExtras,
        action: jax.Array,
        params: CartpoleParams,
    ) -> tuple[mjx.Data, NoExtras]:
        ctrl = self.robot.command(action)
        return self.sim.step(self.sim.model_with(params.model), data, ctrl), extras

    def observation(self, readings: Readings, task: NoExtras) -> jax.Array:
        """Cart position, cos and sin of the pole angle, cart velocity, pole angular
        velocity."""
        (x, x_dot), (theta, theta_dot) = self.robot.cart(readings), self.robot.pole(readings)
        return jnp.stack([x, jnp.cos(theta), jnp.sin(theta), x_dot, theta_dot])

    def _reward(
        self,
        prev: mjx.Data,
        data: mjx.Data,
        action: jax.Array,
        extras: NoExtras,
        params: CartpoleParams,
    ) -> tuple[jax.Array, dict[str, jax.Array]]:
        readings = self.robot.sense(data)
        (x, _), (theta, theta_dot) = self.robot.cart(readings), self.robot.pole(readings)
        upright = (jnp.cos(theta) + 1.0) / 2.0
        centered = (1.0 + tolerance(x, margin=2.0)) / 2.0
        small_control = (
            4.0 + tolerance(action[0], margin=1.0, value_at_margin=0.0, sigmoid="quadratic")
        ) / 5.0
        small_velocity = (1.0 + tolerance(theta_dot, margin=5.0)) / 2.0
        reward = upright * centered * small_control * small_velocity
        return reward.astype(jnp.float32), {}

    def _terminated(self, data: mjx.Data, extras: NoExtras, params: CartpoleParams) -> jax.Array:
        x, _ = self.robot.cart(self.robot.sense(data))
        return jnp.abs(x) > self.config.cart_limit
