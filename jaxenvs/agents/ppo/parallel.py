"""Data-parallel PPO: a program per device of a 1-D mesh, meeting once per gradient step.

:func:`over_mesh` turns a trainer whose functions are written for one device's share
(built with :class:`~jaxenvs.agents.ppo.devices.Devices` of the mesh's size) into one
whose ``init`` and ``chunk`` take and give whole-mesh arrays, as ``jax.shard_map``\\ s:

* each device resets and steps its own slice of envs with its own keys (nothing is
  decided across devices at an env step), computes its own advantages and shuffles its
  own minibatches;
* the devices meet once per gradient step (one ``pmean`` of the gradients and the loss
  figures, after which every device takes the same optimiser step on its copy of the
  parameters) and once per rollout (one ``psum`` that merges the normaliser statistics
  and adds the episode figures, one ``pmax`` of the best return).

The runner state comes back with its env batch (``env_state``, ``disc_return``) split
over the mesh and everything else replicated. ``vmap`` over seeds works outside the
``shard_map`` as for a one-device trainer.
"""

from __future__ import annotations

import dataclasses
from typing import Any

from jax.sharding import Mesh, PartitionSpec

from jaxenvs.agents.base import Trainer
from jaxenvs.agents.ppo.devices import Devices
from jaxenvs.agents.ppo.policy import RunnerState
from jaxenvs.core import placement


def mesh_devices(mesh: Mesh) -> Devices:
    """The :class:`Devices` of a 1-D ``mesh`` (``ValueError`` for any other)."""
    if len(mesh.axis_names) != 1:
        raise ValueError(f"PPO runs over a 1-D mesh, got axes {mesh.axis_names}")
    return Devices(mesh.size, str(mesh.axis_names[0]))


def state_specs(axis: str, critic: bool) -> RunnerState:
    """Where a runner state's fields live over a mesh axis ``axis``: the env batch split
    along its leading axis, the rest replicated (``critic``: the state keeps critic
    statistics)."""
    split: Any = PartitionSpec(axis)
    whole: Any = PartitionSpec()
    return RunnerState(
        params=whole,
        opt_state=whole,
        obs_stats=whole,
        ret_stats=whole,
        disc_return=split,
        env_state=split,
        key=whole,
        env_steps=whole,
        episodes=whole,
        updates=whole,
        critic_stats=whole if critic else None,
    )


def over_mesh(trainer: Trainer, mesh: Mesh, critic: bool) -> Trainer:
    """``trainer`` (one device's share, see the module docstring) with ``init`` and
    ``chunk`` run by every device of ``mesh``."""
    axis = mesh_devices(mesh).axis
    specs, whole = state_specs(axis, critic), PartitionSpec()
    init = placement.shard_map_lean(trainer.init, mesh, (whole,), specs)
    chunk = placement.shard_map_lean(trainer.chunk, mesh, (specs,), (specs, whole))
    # the stages are one device's share: over the mesh the chunk is one program
    return dataclasses.replace(trainer, init=init, chunk=chunk, stages=None)
