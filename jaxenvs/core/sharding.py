"""Spread a batch of envs over several devices and hosts, laid out by the caller.

One mechanism, JAX's own SPMD partitioning: a 1-D :class:`jax.sharding.Mesh` whose axis
``"envs"`` spans the devices, the leading env-batch axis of every env-state leaf sharded
over it (``PartitionSpec("envs")``), everything else (network parameters, optimiser state,
counters) replicated (``PartitionSpec()``). Programs are ordinary ``jax.jit`` functions
with ``in_shardings``/``out_shardings``; the compiler inserts the collectives (the
``jnp.any(done)`` of the auto-reset, the gradient mean of PPO) itself. No ``pmap``, no
processes, sockets or queues of our own.

    mesh = make_mesh(2)                          # first 2 devices; None = all of them
    validate_batch(4096, mesh.size)              # raises if 4096 does not split evenly
    rollout = make_sharded_rollout(benv, mesh, steps=100)
    state, rewards = rollout(jax.random.key(0))  # both sharded over the 2 devices

A trainer's state over the same mesh: :func:`jaxenvs.run.placement.shard_trainer_fns`.
How many devices a batch spreads over by default: :mod:`jaxenvs.core.placement`.

The same code runs on one CPU (a mesh of one device), on several GPUs of one host, and on
several hosts after :func:`maybe_initialize_distributed`. On a CPU-only machine, test the
multi-device path by setting ``XLA_FLAGS=--xla_force_host_platform_device_count=N`` before
JAX initialises.

**Several hosts.** Start one process per host with the same program and these variables
(JAX itself reads ``JAX_COORDINATOR_ADDRESS``; the other two are this project's):

=========================  ==============================================================
``JAX_COORDINATOR_ADDRESS``  ``host:port`` of process 0, reachable from every host
``JAX_NUM_PROCESSES``        number of processes (one per host)
``JAX_PROCESS_ID``           this process's index, 0 .. ``JAX_NUM_PROCESSES - 1``
=========================  ==============================================================

::

    # on host 0                                  # on host 1
    export JAX_COORDINATOR_ADDRESS=host0:1234    export JAX_COORDINATOR_ADDRESS=host0:1234
    export JAX_NUM_PROCESSES=2                   export JAX_NUM_PROCESSES=2
    export JAX_PROCESS_ID=0                      export JAX_PROCESS_ID=1
    jaxenvs train Reacher-v0 --num-envs 8192     jaxenvs train Reacher-v0 --num-envs 8192

Under SLURM (``srun``) or Open MPI (``mpirun``) the variables are not needed: JAX reads the
launcher's own. :func:`maybe_initialize_distributed` then calls
:func:`jax.distributed.initialize`, after which :func:`jax.devices` lists every host's
devices, the mesh spans them all and ``num_envs`` counts envs over all hosts. Every
sharded array is created inside a jitted program from a key that all processes share, so
no host ever sends env states to another.
"""

from __future__ import annotations

import os
from collections.abc import Callable, Sequence
from typing import Any

import jax
import numpy as np
from jax.sharding import Mesh, NamedSharding, PartitionSpec

from jaxenvs.actions import random_actions
from jaxenvs.core import BatchedEnv, State
from jaxenvs.core.placement import ENV_AXIS, check_count, check_divisible
from jaxenvs.core.xla import jit

PyTree = Any

#: the environment variables :func:`maybe_initialize_distributed` reads.
DISTRIBUTED_ENV_VARS = ("JAX_COORDINATOR_ADDRESS", "JAX_NUM_PROCESSES", "JAX_PROCESS_ID")


# --------------------------------------------------------------------------- hosts
def _launcher_detected(environ: dict[str, str] | os._Environ[str]) -> bool:
    """True under a multi-process SLURM step or Open MPI job (JAX auto-detects those)."""
    if int(environ.get("SLURM_NTASKS", "1") or 1) > 1 and "SLURM_JOB_ID" in environ:
        return True
    return int(environ.get("OMPI_COMM_WORLD_SIZE", "1") or 1) > 1


def distributed_args(
    environ: dict[str, str] | os._Environ[str] | None = None,
) -> dict[str, Any] | None:
    """The arguments of :func:`jax.distributed.initialize` the environment asks for.

    ``None`` means a single process (nothing set); ``{}`` means a launcher JAX detects
    itself (SLURM, Open MPI). Raises ``ValueError`` naming the missing variables when only
    some of :data:`DISTRIBUTED_ENV_VARS` are set or when they are not integers.
    """
    environ = os.environ if environ is None else environ
    present = [name for name in DISTRIBUTED_ENV_VARS if environ.get(name)]
    if not present:
        return {} if _launcher_detected(environ) else None
    missing = [name for name in DISTRIBUTED_ENV_VARS if name not in present]
    if missing:
        raise ValueError(
            f"multi-host setup is incomplete: {', '.join(present)} set but "
            f"{', '.join(missing)} missing (set all of {', '.join(DISTRIBUTED_ENV_VARS)})"
        )
    try:
        num_processes = int(environ["JAX_NUM_PROCESSES"])
        process_id = int(environ["JAX_PROCESS_ID"])
    except ValueError:
        raise ValueError(
            "JAX_NUM_PROCESSES and JAX_PROCESS_ID must be integers, got "
            f"{environ['JAX_NUM_PROCESSES']!r} and {environ['JAX_PROCESS_ID']!r}"
        ) from None
    if num_processes < 1 or not 0 <= process_id < num_processes:
        raise ValueError(
            f"need JAX_NUM_PROCESSES >= 1 and 0 <= JAX_PROCESS_ID < JAX_NUM_PROCESSES, got "
            f"{num_processes} and {process_id}"
        )
    return {
        "coordinator_address": environ["JAX_COORDINATOR_ADDRESS"],
        "num_processes": num_processes,
        "process_id": process_id,
    }


def maybe_initialize_distributed(
    environ: dict[str, str] | os._Environ[str] | None = None,
) -> bool:
    """Call :func:`jax.distributed.initialize` if the environment describes several hosts.

    Call it first thing, before any JAX computation. Returns True if this process is (now)
    part of a multi-process run. Safe to call twice.
    """
    args = distributed_args(environ)
    if args is None:
        return False
    if not jax.distributed.is_initialized():
        jax.distributed.initialize(**args)
    return True


# --------------------------------------------------------------------------- mesh
def resolve_devices(devices: int | None = None) -> list[jax.Device]:
    """The first ``devices`` of :func:`jax.devices` (all of them for ``None``)."""
    available = jax.devices()
    if devices is None:
        return list(available)
    n = check_count(devices, len(available), available[0].platform)
    return list(available[:n])


def make_mesh(devices: int | Sequence[jax.Device] | None = None) -> Mesh:
    """A 1-D mesh with axis :data:`ENV_AXIS` over ``devices``.

    ``devices`` is a count (the first N of :func:`jax.devices`), an explicit list of
    devices, or ``None`` for every device of every host.
    """
    if devices is None or isinstance(devices, int):
        devs = resolve_devices(devices)
    else:
        devs = list(devices)
        if not devs:
            raise ValueError("make_mesh needs at least one device")
    return Mesh(np.array(devs), (ENV_AXIS,))


def validate_batch(num_envs: int, devices: int | Mesh) -> None:
    """Raise ``ValueError`` unless ``num_envs`` splits evenly over ``devices``."""
    n = devices.size if isinstance(devices, Mesh) else int(devices)
    check_divisible(num_envs, n, hint=" (--devices)")


def batch_sharding(mesh: Mesh, axis: int = 0) -> NamedSharding:
    """Axis ``axis`` (the env batch; default the leading one) split over the mesh, the
    rest of each array whole."""
    return NamedSharding(mesh, PartitionSpec(*([None] * axis), ENV_AXIS))


def replicated(mesh: Mesh) -> NamedSharding:
    """A full copy on every device of the mesh."""
    return NamedSharding(mesh, PartitionSpec())


# --------------------------------------------------------------------------- trees
KeyPath = tuple[Any, ...]
LeafPredicate = Callable[[KeyPath, Any], bool]


def _path_names(path: KeyPath) -> list[str]:
    names = []
    for entry in path:
        for attr in ("name", "key", "idx"):
            if hasattr(entry, attr):
                names.append(str(getattr(entry, attr)))
                break
    return names


def under_fields(*fields: str) -> LeafPredicate:
    """A predicate true for leaves whose path passes through an attribute/key in ``fields``.

    E.g. ``under_fields("env_state", "obs")`` picks the env-batch leaves of a runner state
    NamedTuple with those fields.
    """
    wanted = set(fields)

    def pred(path: KeyPath, leaf: Any) -> bool:
        del leaf
        return bool(wanted.intersection(_path_names(path)))

    return pred


def tree_shardings(
    tree: PyTree, mesh: Mesh, batched: LeafPredicate | None = None, axis: int = 0
) -> PyTree:
    """A pytree of shardings matching ``tree`` (arrays or ``ShapeDtypeStruct``s).

    Leaves for which ``batched(path, leaf)`` is true (default: every leaf with more than
    ``axis`` axes) get :func:`batch_sharding` on ``axis``; the others are replicated.
    """

    def pick(path: KeyPath, leaf: Any) -> NamedSharding:
        is_batched = batched(path, leaf) if batched is not None else True
        if is_batched and np.ndim(leaf) > axis:
            return batch_sharding(mesh, axis)
        return replicated(mesh)

    return jax.tree_util.tree_map_with_path(pick, tree)


def _check_leading(tree: PyTree, shardings: PyTree, mesh: Mesh) -> None:
    flat, _ = jax.tree_util.tree_flatten_with_path(tree)
    flat_s = jax.tree.leaves(shardings, is_leaf=lambda x: isinstance(x, NamedSharding))
    for (path, leaf), sh in zip(flat, flat_s, strict=True):
        if sh.spec != PartitionSpec():
            try:
                validate_batch(int(np.shape(leaf)[list(sh.spec).index(ENV_AXIS)]), mesh.size)
            except ValueError as err:
                where = jax.tree_util.keystr(path) or "the array"
                raise ValueError(f"{where}: {err}") from None


def shard_batch(tree: PyTree, mesh: Mesh, batched: LeafPredicate | None = None) -> PyTree:
    """Place ``tree`` on the mesh: batched leaves split on their leading axis, rest copied.

    For arrays already in this process. Multi-host runs should instead create their state
    inside a jitted function with ``out_shardings`` (see :func:`shard_jit`).
    """
    shardings = tree_shardings(tree, mesh, batched)
    _check_leading(tree, shardings, mesh)
    return jax.device_put(tree, shardings)


def constrain_batch(tree: PyTree, mesh: Mesh, batched: LeafPredicate | None = None) -> PyTree:
    """Inside a traced function: ask the compiler to keep ``tree`` laid out as
    :func:`shard_batch` would place it."""
    return jax.lax.with_sharding_constraint(tree, tree_shardings(tree, mesh, batched))


def shard_jit(
    fn: Callable[..., Any],
    mesh: Mesh,
    example_args: Sequence[Any],
    *,
    batched: LeafPredicate | None = None,
    donate_argnums: int | Sequence[int] = (),
) -> Callable[..., Any]:
    """``jax.jit(fn)`` with inputs and outputs pinned to the mesh layout.

    ``example_args`` (arrays or ``ShapeDtypeStruct``s) give the argument structure; the
    output structure comes from :func:`jax.eval_shape`. Leaves chosen by ``batched``
    (default: every leaf with an axis) are split over the env axis, the rest replicated.
    """
    out = jax.eval_shape(fn, *example_args)
    in_shardings = tuple(tree_shardings(a, mesh, batched) for a in example_args)
    out_shardings = tree_shardings(out, mesh, batched)
    return jit(
        fn,
        in_shardings=in_shardings,
        out_shardings=out_shardings,
        donate_argnums=donate_argnums,
    )


# --------------------------------------------------------------------------- envs
def sharded_reset(benv: BatchedEnv, mesh: Mesh) -> Callable[[jax.Array], State]:
    """A jitted ``reset(key) -> State`` whose env batch lives split over ``mesh``.

    Raises ``ValueError`` if ``benv.num_envs`` does not divide over the mesh.
    """
    validate_batch(benv.num_envs, mesh)
    benv = benv.on_one_device()  # placed by this function's own shardings
    key = jax.random.key(0)
    return shard_jit(benv.reset, mesh, (jax.ShapeDtypeStruct(key.shape, key.dtype),))


def make_sharded_rollout(
    benv: BatchedEnv,
    mesh: Mesh,
    steps: int,
    policy: Callable[[State, jax.Array], jax.Array] | None = None,
) -> Callable[[jax.Array], tuple[State, jax.Array]]:
    """A jitted ``rollout(key) -> (final_state, rewards)`` over ``mesh``.

    Resets ``benv``, then takes ``steps`` batched (auto-resetting) steps with
    ``policy(state, key) -> actions`` (default: uniform random actions). ``rewards`` has
    shape ``(steps, num_envs)``; it and every leaf of ``final_state`` come back split over
    the mesh along the env axis.
    """
    validate_batch(benv.num_envs, mesh)
    benv = benv.on_one_device()  # placed by this function's own shardings
    if policy is None:

        def policy(state: State, key: jax.Array) -> jax.Array:
            del state
            return random_actions(benv.env, key, (benv.num_envs,))

    def rollout(key: jax.Array) -> tuple[State, jax.Array]:
        reset_key, run_key = jax.random.split(key)
        state = constrain_batch(benv.reset(reset_key), mesh)

        def body(s: State, k: jax.Array) -> tuple[State, jax.Array]:
            action = jax.lax.with_sharding_constraint(policy(s, k), batch_sharding(mesh))
            s = constrain_batch(benv.step(s, action), mesh)
            return s, s.reward

        keys = jax.random.split(run_key, steps)
        state, rewards = jax.lax.scan(body, state, keys, unroll=benv.scan_unroll)
        return state, rewards

    key = jax.random.key(0)
    example = jax.ShapeDtypeStruct(key.shape, key.dtype)
    out = jax.eval_shape(rollout, example)
    state_sh = tree_shardings(out[0], mesh)
    reward_sh = NamedSharding(mesh, PartitionSpec(None, ENV_AXIS))
    return jit(rollout, in_shardings=(replicated(mesh),), out_shardings=(state_sh, reward_sh))


def make_sharded_steps(
    benv: BatchedEnv,
    mesh: Mesh,
    steps: int,
    policy: Callable[[State, jax.Array], jax.Array] | None = None,
) -> tuple[Callable[[jax.Array], State], Callable[[State, jax.Array], State]]:
    """``(reset(key) -> state, run(state, key) -> state)`` over ``mesh``, for timing.

    ``run`` takes ``steps`` batched steps (default policy: uniform random actions) and
    donates its input state, so a loop ``state = run(state, key)`` keeps one env batch
    resident, split over the devices, with no reset between calls.
    """
    validate_batch(benv.num_envs, mesh)
    benv = benv.on_one_device()  # placed by this function's own shardings
    if policy is None:

        def policy(state: State, key: jax.Array) -> jax.Array:
            del state
            return random_actions(benv.env, key, (benv.num_envs,))

    def run(state: State, key: jax.Array) -> State:
        def body(s: State, k: jax.Array) -> tuple[State, None]:
            action = jax.lax.with_sharding_constraint(policy(s, k), batch_sharding(mesh))
            return constrain_batch(benv.step(s, action), mesh), None

        keys = jax.random.split(key, steps)
        return jax.lax.scan(body, state, keys, unroll=benv.scan_unroll)[0]

    reset = sharded_reset(benv, mesh)
    key = jax.random.key(0)
    example = jax.ShapeDtypeStruct(key.shape, key.dtype)
    state_sh = tree_shardings(jax.eval_shape(benv.reset, example), mesh)
    run_fn = jit(
        run,
        in_shardings=(state_sh, replicated(mesh)),
        out_shardings=state_sh,
        donate_argnums=0,
    )
    return reset, run_fn


def sharded_rollout(
    benv: BatchedEnv,
    key: jax.Array,
    steps: int,
    devices: int | Mesh | None = None,
    policy: Callable[[State, jax.Array], jax.Array] | None = None,
) -> tuple[State, jax.Array]:
    """Run :func:`make_sharded_rollout` once on ``devices`` (a count, a mesh or all)."""
    mesh = devices if isinstance(devices, Mesh) else make_mesh(devices)
    return make_sharded_rollout(benv, mesh, steps, policy)(key)


def num_shards(tree: PyTree) -> int:
    """The smallest number of devices any leaf of ``tree`` is spread over (for checks)."""
    return min(leaf.sharding.num_devices for leaf in jax.tree.leaves(tree))


def is_split(x: jax.Array, mesh: Mesh, axis: int = 0) -> bool:
    """True if ``x`` lives on every device of ``mesh`` with axis ``axis`` divided."""
    sh = x.sharding
    if sh.device_set != set(mesh.devices.flat):
        return False
    return sh.shard_shape(x.shape)[axis] == x.shape[axis] // mesh.size


def is_replicated(x: jax.Array, mesh: Mesh) -> bool:
    """True if every device of ``mesh`` holds all of ``x``."""
    sh = x.sharding
    return sh.device_set == set(mesh.devices.flat) and sh.is_fully_replicated
