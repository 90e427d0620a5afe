"""Small shaped-reward helpers (DeepMind Control Suite style tolerance functions)."""

from __future__ import annotations

import math
from typing import Literal

import jax
import jax.numpy as jnp


def tolerance(
    x: jax.Array,
    bounds: tuple[float, float] = (0.0, 0.0),
    margin: float = 0.0,
    sigmoid: Literal["gaussian", "quadratic"] = "gaussian",
    value_at_margin: float = 0.1,
) -> jax.Array:
    """1 inside ``bounds``, falling smoothly to ``value_at_margin`` at ``margin`` outside.

    ``gaussian``: ``exp(-0.5 (d * s)^2)`` with ``s = sqrt(-2 ln value_at_margin)``;
    ``quadratic``: ``1 - (d * s)^2`` clipped at 0 with ``s = sqrt(1 - value_at_margin)``,
    where ``d`` is the distance outside the bounds divided by ``margin``.
    """
    lower, upper = bounds
    in_bounds = (x >= lower) & (x <= upper)
    if margin == 0.0:
        return jnp.where(in_bounds, 1.0, 0.0)
    d = jnp.where(x < lower, lower - x, x - upper) / margin
    if sigmoid == "gaussian":
        scale = math.sqrt(-2.0 * math.log(value_at_margin))
        value = jnp.exp(-0.5 * (d * scale) ** 2)
    elif sigmoid == "quadratic":
        scale = math.sqrt(1.0 - value_at_margin)
        value = jnp.where(jnp.abs(d * scale) < 1.0, 1.0 - (d * scale) ** 2, 0.0)
    else:
        raise ValueError(f"unknown sigmoid {sigmoid!r}")
    return jnp.where(in_bounds, 1.0, value)


# ----------------------------------------------------------------- legged-robot terms
def servo_power(actuator_force: jax.Array, joint_vel: jax.Array) -> jax.Array:
    """The servos' mechanical power, sum |torque x joint speed| (W): an energy penalty."""
    return jnp.sum(jnp.abs(actuator_force * joint_vel))


def roll_pitch_rate_sq(gyro: jax.Array) -> jax.Array:
    """The squared roll and pitch rates of a body-frame gyro reading (rad^2/s^2); yaw
    (turning) is free."""
    return jnp.sum(jnp.square(gyro[:2]))
