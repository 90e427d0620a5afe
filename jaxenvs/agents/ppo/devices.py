"""The devices one PPO program runs on, as that program sees them.

A PPO program runs on each device of a 1-D mesh (a ``jax.shard_map``,
:mod:`jaxenvs.agents.ppo.parallel`) or on one device. :class:`Devices` is all a program
needs to know of that: how many devices run it and the mesh axis they meet on. Every
cross-device step of PPO is a method here, and on one device each is the identity, so a
one-device program holds no collective and computes exactly what it did before PPO ran
on several devices.
"""

from __future__ import annotations

import dataclasses
from typing import Any

import jax

from jaxenvs.agents.normalize import (
    RunningStats,
    merge_sums,
    shifted_sums,
    stats_empty,
    stats_update,
)
from jaxenvs.core.placement import ENV_AXIS

PyTree = Any


@dataclasses.dataclass(frozen=True)
class Devices:
    """``size`` devices that meet on mesh axis ``axis`` (one: no collective at all)."""

    size: int = 1
    axis: str = ENV_AXIS

    @property
    def parallel(self) -> bool:
        return self.size > 1

    def own_key(self, key: jax.Array) -> jax.Array:
        """This device's key of ``key`` (the key shared by every device): ``key`` itself
        on one device, else ``fold_in(key, device index)``."""
        if not self.parallel:
            return key
        return jax.random.fold_in(key, jax.lax.axis_index(self.axis))

    def mean(self, tree: PyTree) -> PyTree:
        """The mean of ``tree`` over the devices (one ``pmean``)."""
        return jax.lax.pmean(tree, self.axis) if self.parallel else tree

    def sum(self, tree: PyTree) -> PyTree:
        """The sum of ``tree`` over the devices (one ``psum``)."""
        return jax.lax.psum(tree, self.axis) if self.parallel else tree

    def max(self, x: jax.Array) -> jax.Array:
        """The maximum of ``x`` over the devices (one ``pmax``)."""
        return jax.lax.pmax(x, self.axis) if self.parallel else x

    def stats_update(self, stats: RunningStats, batch: jax.Array) -> RunningStats:
        """``stats`` (the same on every device) merged with every device's ``batch``."""
        if not self.parallel:
            return stats_update(stats, batch)
        acc = stats_update(stats_empty(stats.mean.shape), batch)
        return merge_sums(stats, self.sum(shifted_sums(acc, stats.mean)))


#: a program of one device (no collective)
ONE_DEVICE = Devices()
