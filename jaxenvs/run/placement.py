"""Where a training run's arrays live: its mesh, and its programs laid out over it.

The env layer decides how many devices a batch spreads over
(:func:`jaxenvs.core.placement.batch_devices`); :func:`run_mesh` applies that rule to a run's
``num_envs`` and engine. Over a mesh of several devices a run is one of three layouts
(:func:`spread_programs`; docs/devices.md):

* **seeds over devices** (:func:`seeds_over_devices`): with ``num_seeds`` a multiple of the
  device count, each device trains its own seeds, whole, as one program of its own; no
  array crosses devices;
* **a program per device** for a trainer whose ``make_trainer`` takes a ``mesh`` (PPO:
  :mod:`jaxenvs.agents.ppo.parallel`): each device steps its share of the batch and the
  devices meet once per gradient step; a config's ``scaling`` says what its ``num_envs``
  means over several devices (:func:`resolve_scaling`);
* **one program partitioned by the compiler** for the other trainers
  (:func:`shard_trainer_fns`, with :mod:`jaxenvs.core.sharding`'s primitives): the env
  batch split, everything else replicated.

The greedy evaluator runs on the same mesh (:func:`mesh_evaluator`).
"""

from __future__ import annotations

import dataclasses
import inspect
from collections.abc import Callable
from typing import Any

import jax
import numpy as np
from jax.sharding import Mesh, NamedSharding, PartitionSpec

from jaxenvs import registry
from jaxenvs.agents.base import Trainer
from jaxenvs.core import BatchedEnv, Env, placement
from jaxenvs.core.sharding import (
    KeyPath,
    LeafPredicate,
    make_mesh,
    replicated,
    tree_shardings,
    under_fields,
    validate_batch,
)
from jaxenvs.core.xla import jit, jit_once
from jaxenvs.run.evaluation import eval_key, make_evaluator
from jaxenvs.run.run_config import ResolvedConfig, algorithm, seed_keys

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


def run_devices(resolved: ResolvedConfig, devices: int | None) -> int:
    """How many devices a run of ``resolved`` trains over (``devices``: as
    :func:`jaxenvs.run.loop.train` takes it; ``None``: as :func:`run_mesh` picks them, the
    rule of the run's batched env)."""
    if devices is not None:
        return devices
    if jax.process_count() > 1:
        return jax.device_count()
    env = registry.spec(resolved.env_id).factory(resolved.env)
    return BatchedEnv(env, resolved.agent.num_envs).devices


def seeds_over_devices(num_seeds: int, devices: int) -> bool:
    """Whether a run of ``num_seeds`` seeds on ``devices`` devices trains each seed on one
    device (several seeds, a multiple of the device count) rather than every seed over
    all of them."""
    return devices > 1 and num_seeds > 1 and num_seeds % devices == 0


def resolve_scaling(resolved: ResolvedConfig, devices: int | None) -> ResolvedConfig:
    """``resolved`` with its agent config as it trains on the devices the run will use
    (``devices``: as :func:`jaxenvs.run.loop.train` takes it): a config with
    ``scaling: weak`` becomes the ``strong`` config of its whole batch
    (``PPOConfig.on_devices``), which is what a run's config.yaml records, so that a
    resume or an evaluation of the run rebuilds the same batch on any device count.
    Configs without ``scaling`` and strong ones are returned as they are."""
    if getattr(resolved.agent, "scaling", "strong") != "weak":
        return resolved
    n = run_devices(resolved, devices)
    if seeds_over_devices(resolved.train.num_seeds, n):
        n = 1  # every seed on a device of its own: each keeps num_envs envs
    return dataclasses.replace(resolved, agent=resolved.agent.on_devices(n))


@dataclasses.dataclass(frozen=True)
class SpreadPrograms:
    """A run's trainer and its jitted ``vmap``-over-seeds init and chunk over a mesh;
    ``seeds_split``: the seed axis is split over the mesh (:func:`seeds_over_devices`)."""

    trainer: Trainer
    init_fn: Any
    chunk_fn: Any
    seeds_split: bool


def spread_programs(
    resolved: ResolvedConfig, env: Env, trainer: Trainer, mesh: Mesh
) -> SpreadPrograms:
    """The programs of a run over ``mesh`` (several devices), in the layout the module
    docstring describes; ``trainer`` is the run's one-device trainer."""
    num_seeds = resolved.train.num_seeds
    if seeds_over_devices(num_seeds, mesh.size):
        return SpreadPrograms(trainer, *seeds_programs(trainer, mesh), True)
    _, make_trainer = algorithm(resolved.algo)
    if "mesh" in inspect.signature(make_trainer).parameters:
        spread = make_trainer(env, resolved.agent, mesh=mesh)  # type: ignore[call-arg]
        init_fn, chunk_fn = jit_once(jax.vmap(spread.init)), jit(jax.vmap(spread.chunk))
        return SpreadPrograms(spread, init_fn, chunk_fn, False)
    init_fn, chunk_fn = shard_trainer_fns(
        trainer, mesh, resolved.agent.num_envs, num_seeds=num_seeds
    )
    return SpreadPrograms(trainer, init_fn, chunk_fn, False)


def seeds_programs(trainer: Trainer, mesh: Mesh) -> tuple[Any, Any]:
    """Jitted ``init(keys)`` and ``chunk(state)`` of a one-device ``trainer``, ``vmap``-ed
    over seeds whose axis is split over ``mesh``: each device trains its own seeds as a
    program of its own (:func:`jaxenvs.core.placement.shard_map_lean`), and nothing
    crosses devices. The seed count must be a multiple of the mesh's size."""
    split = PartitionSpec(mesh.axis_names[0])
    init = placement.shard_map_lean(jax.vmap(trainer.init), mesh, (split,), split)
    chunk = placement.shard_map_lean(jax.vmap(trainer.chunk), mesh, (split,), (split, split))
    return jit_once(init), jit(chunk)


def mesh_evaluator(
    evaluator: Callable[[PyTree, jax.Array], Any],
    params_shape: PyTree,
    key: jax.Array,
    mesh: Mesh,
    seeds_split: bool,
) -> Callable[[], Callable[[PyTree, jax.Array], Any]]:
    """A function that compiles ``evaluator`` ``vmap``-ed over seeds on ``mesh`` and
    returns it as ``evaluate(params, key)``: the seeds' parameters split over the mesh
    (``seeds_split``, each device evaluating its own seeds) or replicated (every device
    runs the same episodes, and every process of a run over several hosts holds the
    result). ``params_shape`` gives the parameters' structure, ``key`` the key's."""
    whole = replicated(mesh)
    where = NamedSharding(mesh, PartitionSpec(mesh.axis_names[0])) if seeds_split else whole
    impl = jax.random.key_impl(key)

    def run(params: PyTree, key_data: jax.Array) -> Any:
        k = jax.random.wrap_key_data(key_data, impl=impl)
        return jax.vmap(evaluator, in_axes=(0, None))(params, k)

    fn = jit(run, in_shardings=(where, whole), out_shardings=where)
    data_shape = jax.eval_shape(jax.random.key_data, key)

    def compile_evaluate() -> Callable[[PyTree, jax.Array], Any]:
        compiled = fn.lower(params_shape, data_shape).compile()

        def evaluate(params: PyTree, k: jax.Array) -> Any:
            # the key as host data: every process of a run over hosts passes the same
            return compiled(jax.device_put(params, where), np.asarray(jax.random.key_data(k)))

        return evaluate

    return compile_evaluate


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
    """Jitted ``init(keys)`` and ``chunk(runner_state)`` of a one-device ``trainer``
    partitioned over ``mesh`` by the compiler (JAX's SPMD partitioning).

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
    init_fn = jit_once(init, in_shardings=(replicated(mesh),), out_shardings=state_sh)
    chunk_fn = jit(
        chunk,
        in_shardings=(state_sh,),
        out_shardings=(state_sh, jax.tree.map(lambda _: replicated(mesh), metrics)),
    )
    return init_fn, chunk_fn


def mesh_programs(
    resolved: ResolvedConfig, env: Env, trainer: Trainer, mesh: Mesh
) -> tuple[Trainer, Any, Any, Callable[[], Callable[[PyTree, jax.Array], Any]]]:
    """A run's trainer, jitted init and chunk over ``mesh`` (:func:`spread_programs`) and
    the function that compiles its evaluator there (:func:`mesh_evaluator`)."""
    spread = spread_programs(resolved, env, trainer, mesh)
    keys = seed_keys(resolved.train.seed, resolved.train.num_seeds)
    state = spread.init_fn.eval_shape(keys)
    params_shape = jax.eval_shape(jax.vmap(spread.trainer.policy_params), state)
    evaluator = make_evaluator(env, spread.trainer.act, resolved.train.eval_episodes)
    compile_evaluate = mesh_evaluator(
        evaluator, params_shape, eval_key(0), mesh, spread.seeds_split
    )
    return spread.trainer, spread.init_fn, spread.chunk_fn, compile_evaluate
