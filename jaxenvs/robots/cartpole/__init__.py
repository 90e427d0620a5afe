"""The cartpole (``cartpole.xml``): a cart on a slider and a pole on a hinge.

Robot: a 1.0 kg cart on an unlimited, frictionless slider and a 0.1 kg uniform 1.0 m pole
on a hinge (angle 0 = upright, positive tilts the tip toward +x). No contacts, no
constraints, Euler integration.

Actuator: one motor on the slider, ``force``. Command map: ``ctrl`` = the action in
[-1, 1]; the cart force is ``ctrl`` times ``actuator_gear`` (10 N by default; a task may
set another gear in its default params).

Sensors (MJCF ``<sensor>``): encoders on both joints: ``slider_pos`` (m), ``hinge_pos``
(rad), ``slider_vel`` (m/s), ``hinge_vel`` (rad/s). None is privileged.

Randomisable fields (:data:`FIELDS`, ranges :class:`CartpoleRanges`): cart and pole mass
and inertia scaled together by ``mass_scale`` (one factor per body), slider and hinge
damping plus an offset uniform in ``damping_range`` (their default is 0), the motor's gear
scaled by ``gain_scale``. No friction: the cartpole has no contacts.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping
from typing import Any

import jax
import jax.numpy as jnp

from jaxenvs import randomize
from jaxenvs.randomize import Range
from jaxenvs.robots import robot_xml
from jaxenvs.robots.base import Randomization, Robot

FIELDS = ("body_mass", "body_inertia", "dof_damping", "actuator_gear")


@dataclasses.dataclass(frozen=True)
class CartpoleRanges(Randomization):
    """The cartpole's randomisation ranges.

    Attributes:
      mass_scale: factor on the cart's and the pole's mass and inertia.
      damping_range: offset added to the slider's (N s/m) and hinge's (N m s/rad) damping.
      gain_scale: factor on the motor's gear (force per unit command).
    """

    mass_scale: Range = (0.8, 1.2)
    damping_range: Range = (0.0, 0.01)
    gain_scale: Range = (0.9, 1.1)

    def check_ranges(self) -> None:
        randomize.check_range("mass_scale", self.mass_scale, positive=True)
        randomize.check_range("damping_range", self.damping_range, min_low=0.0)
        randomize.check_range("gain_scale", self.gain_scale, positive=True)


class Cartpole(Robot):
    """The cartpole robot (module docstring). ``qpos`` and ``qvel`` are (slider, hinge)."""

    xml = robot_xml("cartpole")
    fields = FIELDS

    def sample_fields(
        self, key: jax.Array, fields: Mapping[str, jax.Array], config: Any
    ) -> dict[str, jax.Array]:
        """``fields`` randomised by ``config``'s :class:`CartpoleRanges`."""
        out = dict(fields)
        # one PRNG call for every factor (jaxenvs.randomize.uniforms)
        mass, damping, gear = randomize.uniforms(
            key,
            [
                (config.mass_scale, out["body_mass"].shape[:1]),
                (config.damping_range, out["dof_damping"].shape),
                (config.gain_scale, out["actuator_gear"].shape[:1]),
            ],
        )
        out["body_mass"] = randomize.scaled(out["body_mass"], mass)
        out["body_inertia"] = randomize.scaled(out["body_inertia"], mass)
        out["dof_damping"] = randomize.shifted(out["dof_damping"], damping)
        out["actuator_gear"] = randomize.scaled(out["actuator_gear"], gear)
        return out

    @staticmethod
    def cart(readings: Mapping[str, jax.Array]) -> tuple[jax.Array, jax.Array]:
        """The cart's position (m) and velocity (m/s), scalars."""
        return readings["slider_pos"][0], readings["slider_vel"][0]

    @staticmethod
    def pole(readings: Mapping[str, jax.Array]) -> tuple[jax.Array, jax.Array]:
        """The pole's angle (rad, 0 upright) and angular velocity (rad/s), scalars."""
        return readings["hinge_pos"][0], readings["hinge_vel"][0]

    @staticmethod
    def state(readings: Mapping[str, jax.Array]) -> jax.Array:
        """(cart position, cart velocity, pole angle, pole angular velocity)."""
        return jnp.stack([*Cartpole.cart(readings), *Cartpole.pole(readings)])
