"""``HexapodOneLeg-v0``: one hexapod leg on a fixed base (the rig) puts its foot tip on a
reachable target; no contacts."""

from __future__ import annotations

import dataclasses
from typing import TYPE_CHECKING

import jax
import jax.numpy as jnp
from flax import struct

from jaxenvs import randomize
from jaxenvs.config import require
from jaxenvs.core import Env
from jaxenvs.randomize import Range
from jaxenvs.robots.base import Readings, RobotTask
from jaxenvs.robots.hexapod import JOINT_RANGE, HexapodLeg, leg_tip
from jaxenvs.tasks.hexapod.base import HexapodParams, HexapodRandomization

if TYPE_CHECKING:
    from mujoco import mjx


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
