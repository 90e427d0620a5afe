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
from collections.abc import Callable
from typing import Any

import jax
import jax.extend.core
import jax.numpy as jnp
from jax.sharding import Mesh, PartitionSpec

from jaxenvs.agents.base import Trainer
from jaxenvs.agents.ppo.devices import Devices
from jaxenvs.agents.ppo.policy import RunnerState


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
    init = per_device(trainer.init, mesh, (whole,), specs)
    chunk = per_device(trainer.chunk, mesh, (specs,), (specs, whole))
    return dataclasses.replace(trainer, init=init, chunk=chunk)


def per_device(fn: Callable[..., Any], mesh: Mesh, in_specs: Any, out_specs: Any) -> Any:
    """``jax.shard_map(fn, mesh=mesh, in_specs=in_specs, out_specs=out_specs)`` through
    whose boundary no array with no elements passes: such operands and results (an
    ``mjx.Data``'s contact arrays of a model without contacts, say) are made as zeros of
    their shape on each side, as are ``fn``'s empty closed-over constants (XLA's CPU
    compiler in jax 0.11.2 crashes on a ``shard_map`` whose operands or results mix
    empty and non-empty arrays: :func:`jaxenvs.core.placement.per_device`). The
    specs split a leaf along its leading axis over the mesh's one axis or leave it whole.

    The varying-axes check is off: ``fn`` steps envs with one-device code (loops whose
    carries mix a device's values with constants); what the specs call whole must be the
    same on every device by construction (:mod:`jaxenvs.agents.ppo.devices`).
    """
    shards = mesh.size
    # per result leaf, learnt while fn is traced: its spec and its local shape and dtype
    traced: list[tuple[Any, list[tuple[PartitionSpec, jax.ShapeDtypeStruct]]]] = []

    def local(split: list[jax.Array], whole: list[jax.Array], layout: Any, tree: Any) -> Any:
        given = {"split": iter(split), "whole": iter(whole)}
        args = [
            next(given[kind]) if size else jnp.zeros(shape, dtype)
            for kind, size, shape, dtype in layout
        ]
        closed, out = jax.make_jaxpr(
            lambda *a: fn(*jax.tree.unflatten(tree, a)), return_shape=True
        )(*args)
        consts = [c if c.size else jnp.zeros(c.shape, c.dtype) for c in closed.consts]
        run = jax.extend.core.jaxpr_as_fun(jax.extend.core.ClosedJaxpr(closed.jaxpr, consts))
        results = run(*args)
        specs = _leaf_specs(out_specs, out)
        out_leaves, out_tree = jax.tree.flatten(out)
        traced.append((out_tree, list(zip(specs, out_leaves, strict=True))))
        kept = [(s, y) for s, y, o in zip(specs, results, out_leaves, strict=True) if o.size]
        return [y for s, y in kept if s != PartitionSpec()], [
            y for s, y in kept if s == PartitionSpec()
        ]

    def call(*args: Any) -> Any:
        leaves, tree = jax.tree.flatten(args)
        specs = _leaf_specs(in_specs, args)
        layout = [
            (
                "whole" if s == PartitionSpec() else "split",
                x.size,
                _local_shape(x.shape, s, shards),
                x.dtype,
            )
            for s, x in zip(specs, leaves, strict=True)
        ]
        split = [x for s, x in zip(specs, leaves, strict=True) if x.size and s != PartitionSpec()]
        whole = [x for s, x in zip(specs, leaves, strict=True) if x.size and s == PartitionSpec()]
        axis = mesh.axis_names[0]
        mapped = jax.shard_map(
            lambda a, b: local(a, b, layout, tree),
            mesh=mesh,
            in_specs=(PartitionSpec(axis), PartitionSpec()),
            out_specs=(PartitionSpec(axis), PartitionSpec()),
            check_vma=False,
        )
        got_split, got_whole = mapped(split, whole)
        out_tree, info = traced[-1]
        given = {"split": iter(got_split), "whole": iter(got_whole)}
        out = [
            next(given["whole" if s == PartitionSpec() else "split"])
            if y.size
            else jnp.zeros(_global_shape(y.shape, s, shards), y.dtype)
            for s, y in info
        ]
        return jax.tree.unflatten(out_tree, out)

    return call


def _leaf_specs(specs: Any, tree: Any) -> list[PartitionSpec]:
    """The spec of every leaf of ``tree``, from ``specs`` (a prefix of its structure)."""
    nested = jax.tree.map(
        lambda s, sub: jax.tree.map(lambda _: s, sub),
        specs,
        tree,
        is_leaf=lambda x: isinstance(x, PartitionSpec),
    )
    return jax.tree.leaves(nested, is_leaf=lambda x: isinstance(x, PartitionSpec))


def _local_shape(shape: tuple[int, ...], spec: PartitionSpec, shards: int) -> tuple[int, ...]:
    return shape if spec == PartitionSpec() else (shape[0] // shards, *shape[1:])


def _global_shape(shape: tuple[int, ...], spec: PartitionSpec, shards: int) -> tuple[int, ...]:
    return shape if spec == PartitionSpec() else (shape[0] * shards, *shape[1:])
