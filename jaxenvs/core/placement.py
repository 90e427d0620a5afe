"""Where env batches live: the one place that decides devices and meshes.

Three decisions, all here:

* **The CPU's host devices.** MJX on a CPU runs one XLA program per host device, and one
  XLA CPU device keeps about two cores busy (benchmarks/RESULTS.md), so jaxenvs asks XLA
  for :func:`host_devices_for` ``(cores)`` devices: :func:`set_host_devices`, called by
  :func:`jaxenvs.machine.use_cores` before JAX starts its backends.
* **The devices a batch is spread over.** A batch of ``num_envs`` envs is spread over
  ``n`` devices by splitting its leading (env) axis over a 1-D mesh whose axis is
  :data:`ENV_AXIS`; ``num_envs`` must then be a multiple of ``n``. :func:`batch_devices`
  picks ``n``: by default every local device that the batch divides over, under MJX, and
  under the C engine from a task's ``c_envs_per_device`` envs a device (each device's
  engine call steps its slice with its share of the engine's threads:
  :mod:`jaxenvs.physics.cengine`; ``None`` keeps a C batch on one device).
  :class:`jaxenvs.core.BatchedEnv` keeps its batch on :func:`local_mesh` ``(n)`` through
  :func:`spread` (one program the compiler partitions) or :func:`per_device` (a program
  per device, for a C batch's step on a CPU); the runner spreads its training state over
  the same count (:mod:`jaxenvs.run.programs`).
* **Placing it yourself.** ``devices=1`` (``BatchedEnv.on_one_device()``) keeps a batch
  unspread, for callers that lay it out with their own shardings
  (:mod:`jaxenvs.core.sharding`'s meshes over every host's devices, which check their sizes with
  :func:`check_count` and :func:`check_divisible`).

Every error is a ``ValueError`` that names the numbers involved and a valid alternative.
"""

from __future__ import annotations

import os
import warnings
from collections.abc import Callable
from typing import Any

import jax
import jax.extend.core
import jax.numpy as jnp
import numpy as np
from jax.sharding import Mesh, NamedSharding, PartitionSpec

from jaxenvs.physics.figures import C_ENVS_PER_DEVICE

#: name of the mesh axis an env batch is split over (see :mod:`jaxenvs.core.sharding`).
ENV_AXIS = "envs"


# --------------------------------------------------------------------------- the CPU
def host_devices_for(n_cores: int) -> int:
    """XLA host devices for ``n_cores`` cores: one per two cores, at least one."""
    return max(1, n_cores // 2)


def user_chose_host_devices() -> bool:
    """True if the user already set the CPU device count (flag, variable or option)."""
    if "xla_force_host_platform_device_count" in os.environ.get("XLA_FLAGS", ""):
        return True
    if os.environ.get("JAX_NUM_CPU_DEVICES"):
        return True
    return int(getattr(jax.config, "jax_num_cpu_devices", -1) or -1) > 0


def set_host_devices(n: int, strict: bool = True) -> None:
    """Ask XLA for ``n`` CPU host devices, unless the user chose a count.

    JAX fixes the count when it starts its backends (and then refuses a new one): asked
    later for a count the CPU does not have, this raises ``RuntimeError`` naming the fix
    (``strict``) or only warns.
    """
    if user_chose_host_devices():
        return
    try:
        jax.config.update("jax_num_cpu_devices", n)
    except RuntimeError:  # JAX refuses a new count once its backends are up
        have = _cpu_device_count()
        if have != n:
            msg = (
                f"jaxenvs.machine.use_cores came after JAX started: the CPU keeps {have} "
                f"device(s) instead of {n}; call it before the first JAX operation, or "
                f"set XLA_FLAGS=--xla_force_host_platform_device_count={n}"
            )
            if strict:
                raise RuntimeError(msg) from None
            warnings.warn(msg, stacklevel=3)


def _cpu_device_count() -> int:
    try:
        return len(jax.devices("cpu"))
    except RuntimeError:  # no CPU backend
        return 1


# --------------------------------------------------------------------------- counts
def divisible_devices(num_envs: int, available: int) -> int:
    """The most devices, at most ``available``, that ``num_envs`` splits over evenly."""
    return max(d for d in range(1, min(available, num_envs) + 1) if num_envs % d == 0)


def check_count(devices: object, available: int, platform: str, local: bool = False) -> int:
    """``devices`` as an int, after checking it is a positive integer at most ``available``.

    Raises ``ValueError`` otherwise; the message says how to get more devices on a CPU
    (``local=True`` also names :func:`jaxenvs.machine.use_cores`).
    """
    if isinstance(devices, bool) or not isinstance(devices, int) or devices < 1:
        raise ValueError(f"devices must be a positive integer, got {devices!r}")
    if devices > available:
        knob = "call jaxenvs.machine.use_cores first, or " if local else ""
        raise ValueError(
            f"asked for {devices} devices but only {available} are available "
            f"({platform}); on a CPU {knob}set "
            f"XLA_FLAGS=--xla_force_host_platform_device_count={devices} before JAX starts"
        )
    return devices


def check_divisible(num_envs: int, devices: int, hint: str = "") -> None:
    """Raise ``ValueError`` unless ``num_envs`` splits evenly over ``devices``.

    The message names the nearest multiples of ``devices``; ``hint`` is appended to its
    "or fewer devices" (e.g. the command-line option that sets the count).
    """
    if num_envs % devices:
        lower = max(devices, num_envs - num_envs % devices)
        raise ValueError(
            f"num_envs={num_envs} does not divide evenly over {devices} devices: use a "
            f"multiple of {devices} (e.g. {lower} or {lower + devices}), or fewer devices"
            f"{hint}"
        )


def batch_devices(
    num_envs: int,
    devices: int | None,
    physics: str,
    c_envs_per_device: int | None = C_ENVS_PER_DEVICE,
) -> int:
    """How many local devices a batch of ``num_envs`` envs is spread over.

    ``devices=None`` (the default) means all local devices of JAX's default backend (CPU
    host devices or GPUs), or as many of them as ``num_envs`` divides over evenly, with a
    warning when that is fewer. Under the C engine (``physics="c"``) each device gets at
    least ``c_envs_per_device`` envs (the task's figure, :mod:`jaxenvs.physics.figures`): a
    smaller batch spreads over fewer devices, one below that size; ``None`` keeps every
    C batch on one device, stepped by all the engine's threads. An explicit count must
    divide ``num_envs`` and exist, or ``ValueError`` names the nearest valid sizes.
    """
    local = jax.local_device_count()
    available = local
    if devices is None and physics == "c":
        per = num_envs if c_envs_per_device is None else max(c_envs_per_device, 1)
        available = max(1, min(local, num_envs // per))
    if devices is None:
        if available == 1:
            return 1
        n = divisible_devices(num_envs, available)
        # a C batch capped below the local count divides by choice: no warning
        if available == local and n < available and num_envs >= available:
            lower = num_envs - num_envs % available
            warnings.warn(
                f"num_envs={num_envs} does not divide over the {available} local devices: "
                f"spreading over {n} (a multiple of {available}, e.g. {lower} or "
                f"{lower + available}, uses them all)",
                stacklevel=3,
            )
        return n
    check_count(devices, available, jax.default_backend(), local=True)
    check_divisible(num_envs, devices)
    return devices


# --------------------------------------------------------------------------- meshes
def local_mesh(n: int) -> Mesh | None:
    """A 1-D mesh with axis :data:`ENV_AXIS` over the first ``n`` local devices; ``None``
    for one device (nothing to spread)."""
    return None if n == 1 else Mesh(np.array(jax.local_devices()[:n]), (ENV_AXIS,))


def spread(mesh: Mesh | None, fn: Callable[..., Any], *args: Any) -> Any:
    """``fn(first, second, rest)`` with the first two arguments' and the result's leading
    (env) axis split over ``mesh`` (``None``: plain ``fn(*args)``).

    One program over the mesh, not a ``shard_map``: the compiler partitions it and adds
    the one cross-device reduction (the auto-reset's count of finished envs), so every device takes
    the same auto-reset decision and every env's arithmetic is as on one device. The C
    engine's call is partitioned along the env axis too (a ``custom_partitioning`` op,
    :mod:`jaxenvs.physics.cengine`): each device steps its own slice.
    """
    if mesh is None:
        return fn(*args)
    split = NamedSharding(mesh, PartitionSpec(ENV_AXIS))

    def place(tree: Any) -> Any:
        return jax.lax.with_sharding_constraint(tree, jax.tree.map(lambda _: split, tree))

    def run(first: Any, second: Any, rest: Any) -> Any:
        return place(fn(place(first), place(second), rest))

    # jit: inlined when the caller is traced; called eagerly, the task's constants
    # (committed to one device) become part of one program over the mesh. Plain jax.jit:
    # XLA takes compiler options only on the outermost jit
    return jax.jit(run)(*args)


def per_device(mesh: Mesh, fn: Callable[..., Any], *args: Any) -> Any:
    """``fn(first, second, rest)`` run by each device of ``mesh`` on its own slice of the
    first two arguments' leading (env) axis (``rest`` whole on every device), as a
    :func:`jax.shard_map` (:func:`shard_map_lean`); the result's leading axis is split the
    same way.

    Unlike :func:`spread`, nothing is decided across devices: a data-dependent loop in
    ``fn`` (the auto-reset's, sized by the finished envs) runs as many iterations on each
    device as that device's slice needs.
    """
    split, whole = PartitionSpec(ENV_AXIS), PartitionSpec()
    # jit as in spread: inlined when the caller is traced
    return jax.jit(shard_map_lean(fn, mesh, (split, split, whole), split))(*args)


def shard_map_lean(fn: Callable[..., Any], mesh: Mesh, in_specs: Any, out_specs: Any) -> Any:
    """``jax.shard_map(fn, mesh=mesh, in_specs=in_specs, out_specs=out_specs)`` through
    whose boundary no array with no elements passes: such operands and results (an
    ``mjx.Data``'s contact arrays of a model without contacts, say) are made as zeros of
    their shape on each side, as are ``fn``'s empty closed-over constants (XLA's CPU
    compiler in jax 0.11.2 crashes on a ``shard_map`` whose operands or results mix
    empty and non-empty arrays; benchmarks/NOTES.md). The specs split a leaf along its
    leading axis over the mesh's one axis or leave it whole; Python scalars among the
    arguments become arrays, as under ``jit``.

    The varying-axes check is off: ``fn`` steps envs with one-device code (loops whose
    carries mix a device's values with constants); what the specs call whole must be the
    same on every device by construction (a batch's params; a trainer's:
    :mod:`jaxenvs.agents.ppo.devices`).
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
        leaves = [x if isinstance(x, jax.Array | np.ndarray) else jnp.asarray(x) for x in leaves]
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
