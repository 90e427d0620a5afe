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
    :func:`jax.shard_map`; the result's leading axis is split the same way.

    Unlike :func:`spread`, nothing is decided across devices: a data-dependent loop in
    ``fn`` (the auto-reset's, sized by the finished envs) runs as many iterations on each
    device as that device's slice needs. Leaves with no elements (an ``mjx.Data``'s
    contact and constraint arrays of a model without contacts) do not cross the
    ``shard_map``'s boundary: they are made as zeros of their shape on each side (XLA's CPU
    compiler in jax 0.11.2 crashes on a ``shard_map`` whose operands or results mix empty
    and non-empty arrays; benchmarks/NOTES.md).
    """
    first, second, rest = args
    shards = mesh.size
    leaves, tree = jax.tree.flatten((first, second, rest))
    # Python scalars among the leaves (a param given as a float) become arrays, as under jit
    leaves = [x if isinstance(x, jax.Array | np.ndarray) else jnp.asarray(x) for x in leaves]
    num_split = len(jax.tree.leaves((first, second)))
    kept = [i for i, x in enumerate(leaves) if x.size]
    split, whole = PartitionSpec(ENV_AXIS), PartitionSpec()
    specs = [split if i < num_split else whole for i in kept]
    # the result's structure and leaf shapes, learnt while fn is traced
    result: list[tuple[Any, list[jax.ShapeDtypeStruct]]] = []

    def local(kept_leaves: list[jax.Array]) -> list[jax.Array]:
        given = iter(kept_leaves)
        full = [
            next(given) if x.size else jnp.zeros(_slice_shape(x, shards, i < num_split), x.dtype)
            for i, x in enumerate(leaves)
        ]
        # fn's closed-over arrays would cross the boundary as operands too: its empty ones
        # are made here instead (the others cross, replicated)
        closed, out = jax.make_jaxpr(
            lambda *a: fn(*jax.tree.unflatten(tree, a)), return_shape=True
        )(*full)
        consts = [c if c.size else jnp.zeros(c.shape, c.dtype) for c in closed.consts]
        run_fn = jax.extend.core.jaxpr_as_fun(jax.extend.core.ClosedJaxpr(closed.jaxpr, consts))
        out_leaves, out_tree = jax.tree.flatten(out)
        result.append((out_tree, out_leaves))
        return [y for y, s in zip(run_fn(*full), out_leaves, strict=True) if s.size]

    def run(kept_leaves: list[jax.Array]) -> Any:
        # check_vma off: fn is a one-device program (its reset loop's carry mixes the
        # device's own values with constants, which the check would ask to be cast)
        mapped = jax.shard_map(
            local, mesh=mesh, in_specs=(specs,), out_specs=split, check_vma=False
        )
        out = iter(mapped(kept_leaves))
        out_tree, shapes = result[-1]
        return jax.tree.unflatten(
            out_tree,
            [
                next(out) if y.size else jnp.zeros((y.shape[0] * shards, *y.shape[1:]), y.dtype)
                for y in shapes
            ],
        )

    # jit as in spread: inlined when the caller is traced
    return jax.jit(run)([leaves[i] for i in kept])


def _slice_shape(x: Any, shards: int, split: bool) -> tuple[int, ...]:
    """The shape of one device's part of ``x``: its leading axis split ``shards`` ways, or
    whole."""
    return (x.shape[0] // shards, *x.shape[1:]) if split else tuple(x.shape)
