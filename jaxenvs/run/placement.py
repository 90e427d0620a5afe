"""Where a training run's arrays live: its mesh and its runner state laid out over it.

The env layer decides how many devices a batch spreads over
(:func:`jaxenvs.core.placement.batch_devices`); :func:`run_mesh` applies that rule to a run's
``num_envs`` and engine, and :func:`shard_trainer_fns` lays a trainer's state out over the
mesh with :mod:`jaxenvs.core.sharding`'s primitives: the env batch split, everything else
replicated.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import jax
import numpy as np
from jax.sharding import Mesh

from jaxenvs.agents.base import Trainer
from jaxenvs.core import placement
from jaxenvs.core.sharding import (
    KeyPath,
    LeafPredicate,
    make_mesh,
    replicated,
    tree_shardings,
    under_fields,
    validate_batch,
)
from jaxenvs.core.xla import jit

PyTree = Any


def run_mesh(
    num_envs: int,
    physics: str,
    devices: int | None = None,
    c_envs_per_device: int | None = placement.C_ENVS_PER_DEVICE,
) -> Mesh:
    """The mesh a run of ``num_envs`` envs stepped by ``physics`` trains over.

    ``devices=None`` in a single process: the local devices
    :func:`jaxenvs.core.placement.batch_devices` picks for the task's ``c_envs_per_device``
    (as its batched env does). Several processes: every host's devices. A count: the
    first ``devices`` devices.
    """
    if devices is None and jax.process_count() == 1:
        devices = placement.batch_devices(num_envs, None, physics, c_envs_per_device)
    return make_mesh(devices)


#: runner-state fields that may hold the env batch (PPO's and the tabular agents' names);
#: a leaf under one of them is split only if its env axis has ``num_envs`` entries. Every
#: other leaf (network params, Q-table, optimiser state, statistics, counters, keys) is
#: replicated.
ENV_BATCH_FIELDS = ("env_state", "disc_return", "action", "episodes")


def shard_trainer_fns(
    trainer: Trainer,
    mesh: Mesh,
    num_envs: int,
    num_seeds: int | None = None,
    batched: LeafPredicate | None = None,
) -> tuple[Callable[[jax.Array], PyTree], Callable[[PyTree], tuple[PyTree, PyTree]]]:
    """Jitted ``init(keys)`` and ``chunk(runner_state)`` of ``trainer`` over ``mesh``.

    With ``num_seeds`` the two are ``vmap``-ed over a leading seed axis (as the runner
    uses them) and the env axis is axis 1; without it they take one seed. Runner-state
    leaves under :data:`ENV_BATCH_FIELDS` (or those ``batched`` picks) are split along the
    env axis; the rest, network parameters included, are replicated on every device, and
    the compiler adds the cross-device reductions (the gradient mean, the observation
    statistics). Raises ``ValueError`` if ``num_envs`` does not divide over the mesh.
    """
    validate_batch(num_envs, mesh)
    batched = batched or under_fields(*ENV_BATCH_FIELDS)
    init, chunk = trainer.init, trainer.chunk
    axis = 0
    key = jax.random.key(0)
    keys = jax.ShapeDtypeStruct(key.shape, key.dtype)
    if num_seeds is not None:
        init, chunk, axis = jax.vmap(init), jax.vmap(chunk), 1
        keys = jax.ShapeDtypeStruct((num_seeds, *key.shape), key.dtype)

    def env_axis_of(path: KeyPath, leaf: Any) -> bool:
        return batched(path, leaf) and np.shape(leaf)[axis : axis + 1] == (num_envs,)

    state = jax.eval_shape(init, keys)
    state_sh = tree_shardings(state, mesh, env_axis_of, axis)
    metrics = jax.eval_shape(chunk, state)[1]
    init_fn = jit(init, in_shardings=(replicated(mesh),), out_shardings=state_sh)
    chunk_fn = jit(
        chunk,
        in_shardings=(state_sh,),
        out_shardings=(state_sh, jax.tree.map(lambda _: replicated(mesh), metrics)),
    )
    return init_fn, chunk_fn
