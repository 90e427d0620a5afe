"""Pendulum swing-up: a user's own task, written against jaxenvs' public API.

``MyPendulum-v0`` (the task of Gymnasium's Pendulum-v1, on MuJoCo MJX)

* Robot (``pendulum.xml``): a 1 kg bob on a light 1 m rod, hinged about y, angle 0 =
  upright; one motor, ``ctrl`` in [-1, 1] times ``max_torque`` (2 N m: too weak to lift
  the bob directly, so the policy must swing it up).
* Observation (3): ``cos(angle)``, ``sin(angle)``, angular velocity (rad/s), each plus
  Gaussian sensor noise of std ``obs_noise`` (0 by default: exact), drawn from the
  observation key ``Env.step`` hands to ``_observe``.
* Action: Box(1) in [-1, 1], the motor command.
* Reward: ``-(angle^2 + velocity_cost * velocity^2 + torque_cost * torque^2)`` with the
  angle wrapped to [-pi, pi]; 0 is best (upright and still).
* Termination: none. Truncation: ``episode_length`` (200) steps.
* Start: angle uniform in [-pi, pi], velocity uniform in +-``init_velocity``.
* Timing: 0.05 s per control step, 5 Euler substeps of 0.01 s.
"""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path

import jax
import jax.numpy as jnp
from mujoco import mjx

from jaxenvs.config import require
from jaxenvs.core import Env, NoExtras, TaskConfig
from jaxenvs.physics.sim import Sim

XML = Path(__file__).with_name("pendulum.xml")


@dataclasses.dataclass(frozen=True)
class PendulumConfig(TaskConfig):
    """``MyPendulum-v0``: every field can be overridden, e.g. ``make(..., max_torque=3)``.

    Attributes:
      episode_length: steps before truncation.
      timestep, substeps: physics; the control period is their product.
      max_torque: motor torque (N m) at ``|action| = 1``.
      velocity_cost, torque_cost: weights of the penalties in the reward.
      init_velocity: initial angular velocity uniform in +- this (rad/s).
      obs_noise: std of the Gaussian noise added to every observation entry.
    """

    episode_length: int = 200
    timestep: float = 0.01
    substeps: int = 5
    max_torque: float = 2.0
    velocity_cost: float = 0.1
    torque_cost: float = 0.001
    init_velocity: float = 1.0
    obs_noise: float = 0.0

    def validate(self) -> None:
        super().validate()
        require(self.max_torque > 0, "max_torque", "must be positive")
        require(self.init_velocity >= 0, "init_velocity", "must be >= 0")
        require(self.obs_noise >= 0, "obs_noise", "must be >= 0")


class Pendulum(Env[PendulumConfig]):
    """Swing a torque-limited pendulum up and hold it there (see the module docstring)."""

    metric_keys = ("upright",)
    observation_size = 3
    action_size = 1

    def __init__(self, config: PendulumConfig | None = None) -> None:
        config = config or PendulumConfig()
        super().__init__(config, Sim(XML, config.timestep, config.substeps))
        gear = self.sim.default_fields(("actuator_gear",))["actuator_gear"]
        # params: the MJX model fields swapped in at every step (randomisable per env)
        self._params = {"actuator_gear": gear.at[0, 0].set(config.max_torque)}

    @property
    def default_params(self) -> dict[str, jax.Array]:
        return self._params

    def _init(self, key: jax.Array, params: dict[str, jax.Array]) -> tuple[mjx.Data, NoExtras]:
        angle_key, velocity_key = jax.random.split(key)
        angle = jax.random.uniform(angle_key, (1,), minval=-math.pi, maxval=math.pi)
        v = self.config.init_velocity
        velocity = jax.random.uniform(velocity_key, (1,), minval=-v, maxval=v)
        return self.sim.init_data(qpos=angle, qvel=velocity), NoExtras()

    def _act(
        self,
        key: jax.Array,
        data: mjx.Data,
        extras: NoExtras,
        action: jax.Array,
        params: dict[str, jax.Array],
    ) -> tuple[mjx.Data, NoExtras]:
        return self.sim.step(self.sim.model_with(params), data, action), extras

    def _observe(
        self, key: jax.Array, data: mjx.Data, extras: NoExtras, params: dict[str, jax.Array]
    ) -> jax.Array:
        angle = data.qpos[0]
        obs = jnp.stack([jnp.cos(angle), jnp.sin(angle), data.qvel[0]])
        if self.config.obs_noise > 0:  # a config constant: no retrace
            obs = obs + self.config.obs_noise * jax.random.normal(key, obs.shape)
        return obs

    def _reward(
        self,
        prev: mjx.Data,
        data: mjx.Data,
        action: jax.Array,
        extras: NoExtras,
        params: dict[str, jax.Array],
    ) -> tuple[jax.Array, dict[str, jax.Array]]:
        c = self.config
        angle = jnp.arctan2(jnp.sin(data.qpos[0]), jnp.cos(data.qpos[0]))  # wrapped
        torque = c.max_torque * action[0]
        cost = angle**2 + c.velocity_cost * data.qvel[0] ** 2 + c.torque_cost * torque**2
        upright = jnp.cos(angle) > 0.95
        return -cost, {"upright": upright}
