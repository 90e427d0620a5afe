"""MuJoCo's C engine behind the functional API (``physics="c"``), for CPUs.

A task's ``reset``/``step`` stay the same pure JAX functions over an ``mjx.Data``; only the
physics step changes. Each control step is one call out of the compiled program into
MuJoCo's batched C API (``mujoco/mjbatch.h``): every env of the batch is stepped on its own
from the full state it holds (``mj_step`` per substep, float64), by the calling thread and
tasks on XLA's own CPU thread pool. From JAX's side it is a pure function: ``jit``, nested
``vmap`` (the call sees every batch axis at once), ``lax.scan``, the auto-reset, sharding
and domain randomisation work, and the same inputs give the same outputs bit for bit at
any thread count.

**Two paths, one result.** The call is the native engine (:mod:`jaxenvs.physics.native`: an XLA FFI
custom call, no Python and no GIL per step, and nothing process-specific in the compiled
program, which names the model by a digest of its content, so programs go into JAX's
persistent cache) when it was built and loads; otherwise a ``jax.pure_callback`` into
``mujoco.batch.Batch``, with the same outputs (tested) at a higher cost per call.
:func:`path` says which one runs and why.

**Devices.** The call is partitioned along the batch (env) axes
(:func:`jax.experimental.custom_partitioning`): when a batch's state is split over several
host devices (:mod:`jaxenvs.core.placement`), each device steps its own slice with
``threads // devices`` threads (at least one), bit for bit as on one device. Inside a
``shard_map`` (:func:`jaxenvs.core.placement.per_device`, a program per device) the call is
a plain one over the device's own slice, with that device's share of the threads; the
callback path is never partitioned, so there too each device's callback sees only its
slice, while in one partitioned program it sees the whole batch. Such a partitioned program
names its partitioning by a key of this process, so JAX's persistent cache does not carry
it to another process; a one-device program is unchanged.

**Fields.** A step reads the state MJX's step reads (:data:`INPUTS`: ``time``, ``qpos``,
``qvel``, ``act``, ``qacc_warmstart``, ``ctrl``, applied forces, ``eq_active``, mocap poses,
``userdata``) and writes the state it advances (:data:`ADVANCED`) and every derived field
``mjx.Data`` shares with MuJoCo's ``mjData`` (body, geom and site poses, centre-of-mass
quantities, ``sensordata``, ``qacc``, actuator quantities, the mass matrix, ...), with MJX's
convention: derived fields describe the state before the last substep. Given ``derived``
(the derived fields a task reads: ``Env.derived_fields``), it writes only those: copying
fields out of every env's ``mjData`` is much of a small model's step, and the others hold
:class:`Unavailable` (reading one raises, naming ``derived_fields``). A field the step
does not compute for this model (``qfrc_inverse``; ``cacc`` without a sensor that needs it)
is 0, as in a fresh ``mjx.Data``. The contact and constraint arrays (``contact``, ``efc_*``),
whose layouts differ between the engines, hold :class:`Unavailable`: reading one raises
:class:`CEngineError` at trace time naming the field.

**Bad states.** MuJoCo resets a state whose positions, velocities or accelerations are
non-finite or huge, with a warning, and carries on. Such an env (and one whose step raised
a warning of a full constraint arena, a bad control, or an error) comes back with every
field but ``time`` NaN, on any step, the first of an episode included, so the task's
divergence check terminates it as under MJX.

**Timers.** MuJoCo's Python bindings install a default clock as ``mjcb_time`` at import,
timing every stage of every step in the process (``mjData.timer``), a quarter of a small
model's step. Native calls turn that default clock off (``engine.cc``); a clock installed
with ``mujoco.set_mjcb_time(fn)`` is kept.

**Params.** ``sim.model_with(fields)`` names model fields by their MuJoCo names
(``body_mass``, ``actuator_gear``, ...). Their values travel with each call, per env, and
are written into the stepping thread's model copy before that env's step: memory grows
with threads, not with envs.
"""

from __future__ import annotations

import functools
import math
import warnings
from collections.abc import Mapping, Sequence
from typing import TYPE_CHECKING, Any

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
from jax.custom_batching import custom_vmap
from jax.experimental.custom_partitioning import custom_partitioning

from jaxenvs.physics import native
from jaxenvs.physics.c_callback import Callback
from jaxenvs.physics.c_layout import (
    ADVANCED,
    BAD_WARNINGS,
    INPUTS,
    SERIAL_WORK,
    CEngineError,
    Layout,
    Unavailable,
    check_model,
    layout,
)

if TYPE_CHECKING:
    from mujoco import mjx


@functools.lru_cache(maxsize=1)
def _warn_fallback_once() -> None:
    warnings.warn(
        "jaxenvs: physics='c' steps through a Python callback, several times slower than "
        f"the native engine: {native.unavailable_reason()}",
        RuntimeWarning,
        stacklevel=4,
    )


def path() -> str:
    """``"native"`` or ``"callback"``: how a C step is called in this process."""
    return "native" if native.available() else "callback"


class CEngine:
    """Steps batches of one model in MuJoCo C from inside JAX programs.

    Args:
      model: the host model to step (timestep, solver options and task edits applied).
      template: an ``mjx.Data`` of the same model (shapes and dtypes of the state).
      threads: the pool's size (``jaxenvs.machine.cpu_threads()``).
      via: ``"native"`` or ``"callback"`` to force a path (tests compare them); default:
        the native engine where it loads (:func:`path`).
      derived: the derived fields to write (``None``: every one it provides).
    """

    def __init__(
        self,
        model: mujoco.MjModel,
        template: mjx.Data,
        threads: int,
        via: str | None = None,
        derived: Sequence[str] | None = None,
    ) -> None:
        check_model(model)
        native.prepare(model)
        if threads < 1:
            raise ValueError(f"threads must be >= 1, got {threads}")
        self.model = model
        self.threads = int(threads)
        self.layout = layout(model, template, derived)
        #: ``"native"`` or ``"callback"``
        self.path = via or path()
        if self.path not in ("native", "callback"):
            raise ValueError(f"via must be 'native' or 'callback', got {via!r}")
        #: the digest native calls name the model by (``None`` on the callback path)
        self.key: str | None = None
        self._callback: Callback | None = None
        if self.path == "native":
            self.key = native.register_model(model)
        else:
            if via is None:
                _warn_fallback_once()
            self._callback = Callback(model, self.threads, self.layout)

    def blank(self, data: mjx.Data) -> mjx.Data:
        """``data`` with the fields this engine does not provide or does not write replaced
        by :class:`Unavailable`."""
        lay = self.layout
        low = {n: Unavailable(n) for n in lay.unavailable}
        low.update({n: Unavailable(n, "undeclared") for n, in_impl in lay.skipped if in_impl})
        top = {n: Unavailable(n, "undeclared") for n, in_impl in lay.skipped if not in_impl}
        return data.replace(_impl=data._impl.replace(**low), **top)

    @functools.lru_cache(maxsize=64)  # noqa: B019 - one engine per Sim, kept for its life
    def field_shape(self, name: str) -> tuple[int, ...]:
        """Shape of model field ``name``; raises CEngineError naming an unknown one."""
        value = getattr(self.model, name, None)
        if not isinstance(value, np.ndarray) or value.dtype.kind != "f":
            raise CEngineError(
                f"physics='c': params field {name!r} is not a floating-point field of "
                "MuJoCo's model, so the C engine cannot apply it (use physics='mjx')"
            )
        return value.shape

    def step(
        self, fields: Mapping[str, jax.Array], data: mjx.Data, ctrl: jax.Array, substeps: int
    ) -> mjx.Data:
        """Hold ``ctrl`` for ``substeps`` C physics steps from ``data`` with ``fields``."""
        if substeps < 1:
            raise ValueError(f"substeps must be >= 1, got {substeps}")
        data = data.replace(ctrl=jnp.asarray(ctrl, data.ctrl.dtype))
        return self._call(fields, data, int(substeps))

    def forward(self, fields: Mapping[str, jax.Array], data: mjx.Data) -> mjx.Data:
        """The derived fields this engine writes (every one it provides, or those named
        in ``derived``) at ``data``'s state (``mj_forward``); the state is kept."""
        out = self._call(fields, data, 0)
        return out.replace(**{n: getattr(data, n) for n in ADVANCED})

    @functools.lru_cache(maxsize=64)  # noqa: B019 - one engine per Sim, kept for its life
    def _stepper(self, substeps: int, names: tuple[str, ...], dtypes: tuple[Any, ...]) -> Any:
        """The engine's call as a function of ``(inputs..., params...)`` (each with the same
        leading batch axes), batched by ``vmap`` and partitioned along those axes.

        Under ``vmap`` every batch axis becomes a leading axis of one call (the rule
        broadcasts unbatched operands, as ``vmap_method="broadcast_all"`` does). A call
        with batch axes is a :func:`jax.experimental.custom_partitioning` op: when its
        operands are split along those axes over several devices, each device steps its
        own slice with ``threads // shards`` threads, and per-env dims stay whole. Inside a
        ``shard_map`` (manual mesh axes) the operands are already one device's slice: a
        plain call with ``threads // devices`` threads. On the callback path the call is
        never partitioned: it sees whatever its program holds (the whole batch in a
        partitioned program, the device's slice inside a ``shard_map``).
        """
        lay = self.layout
        env_in = [lay.shapes[n] for n in lay.inputs] + [self.field_shape(n) for n in names]
        env_out = [lay.shapes[n] for n, _ in lay.outputs]
        qpos = lay.inputs.index("qpos")

        def raw(arrays: Sequence[jax.Array], threads: int) -> list[jax.Array]:
            lead = arrays[qpos].shape[:-1]
            shapes = [
                jax.ShapeDtypeStruct((*lead, *shape), dt)
                for shape, dt in zip(env_out, dtypes, strict=True)
            ]
            return self._raw(substeps, names, threads, arrays, shapes)

        def sharded(arrays: Sequence[jax.Array]) -> list[jax.Array]:
            k = arrays[qpos].ndim - 1
            # unpartitioned: no batch axes; the callback path (a Python callback lowered
            # inside a partitioned op loses its registration, so its call sees the whole
            # batch); GSPMD (the rule below is Shardy's)
            shardy = getattr(jax.config, "jax_use_shardy_partitioner", True)
            if k == 0 or self._callback is not None or not shardy:
                return raw(arrays, self.threads)
            # inside a shard_map (placement.per_device) the arrays are this device's own:
            # a plain call, with this device's share of the threads
            mesh = jax.sharding.get_abstract_mesh()
            manual = math.prod(mesh.shape[a] for a in mesh.manual_axes)
            if manual > 1:
                return raw(arrays, max(1, self.threads // manual))
            return _partitioned(raw, self.threads, k, env_in, env_out, qpos)(*arrays)

        @custom_vmap
        def run(arrays: tuple[jax.Array, ...]) -> list[jax.Array]:
            return sharded(arrays)

        @run.def_vmap
        def _rule(
            axis_size: int, in_batched: Any, arrays: tuple[jax.Array, ...]
        ) -> tuple[list[jax.Array], list[bool]]:
            batched = tuple(
                a if b else jnp.broadcast_to(a, (axis_size, *a.shape))
                for a, b in zip(arrays, in_batched[0], strict=True)
            )
            outs = run(batched)
            return outs, [True] * len(outs)

        return run

    def _raw(
        self,
        substeps: int,
        names: tuple[str, ...],
        threads: int,
        arrays: Sequence[jax.Array],
        shapes: Sequence[jax.ShapeDtypeStruct],
    ) -> list[jax.Array]:
        """One call of the engine over every env of ``arrays`` with ``threads`` threads."""
        lay = self.layout
        if self._callback is None:
            call = jax.ffi.ffi_call(native.TARGET, shapes, vmap_method="broadcast_all")
            return list(
                call(
                    *arrays,
                    model=self.key,
                    substeps=np.int64(substeps),
                    threads=np.int64(threads),
                    serial_work=np.int64(SERIAL_WORK),
                    inputs=",".join(lay.inputs),
                    params=",".join(names),
                    outputs=",".join(n for n, _ in lay.outputs),
                )
            )
        host = functools.partial(self._callback, substeps, names, threads)
        return list(jax.pure_callback(host, shapes, *arrays, vmap_method="broadcast_all"))

    def _call(self, fields: Mapping[str, jax.Array], data: mjx.Data, substeps: int) -> mjx.Data:
        lay = self.layout
        dtype = data.qpos.dtype
        names = tuple(sorted(fields))
        params = []
        for name in names:
            value = jnp.asarray(fields[name], dtype)
            if value.shape != self.field_shape(name):
                raise CEngineError(
                    f"physics='c': params field {name!r} has shape {value.shape}, the "
                    f"model's is {self.field_shape(name)}"
                )
            params.append(value)
        args = [jnp.asarray(getattr(data, n)) for n in lay.inputs]
        args = [a if a.dtype == jnp.bool_ else a.astype(dtype) for a in args]
        impl = data._impl
        leaves = [jnp.asarray(getattr(impl if in_impl else data, n)) for n, in_impl in lay.outputs]
        dtypes = tuple(jnp.dtype(leaf.dtype) for leaf in leaves)
        results = self._stepper(substeps, names, dtypes)((*args, *params))
        top = {n: r for (n, in_impl), r in zip(lay.outputs, results, strict=True) if not in_impl}
        low = {n: r for (n, in_impl), r in zip(lay.outputs, results, strict=True) if in_impl}
        return data.replace(_impl=impl.replace(**low), **top)


def _partitioned(
    raw: Any,
    threads: int,
    k: int,
    env_in: Sequence[tuple[int, ...]],
    env_out: Sequence[tuple[int, ...]],
    qpos: int,
) -> custom_partitioning:
    """``raw(arrays, threads)`` as an op the SPMD partitioner splits along the ``k``
    leading (batch) axes that every operand and result share.

    Its Shardy rule gives the batch axes one factor each, common to every operand and
    result, and each per-env axis a factor of its own that must stay whole. Each device
    then calls ``raw`` on its slice with ``threads // shards`` threads (at least one), so
    the devices' calls together use about the engine's threads, not that many each.
    """
    batch = [f"b{i}" for i in range(k)]
    whole: list[str] = []

    def operand(prefix: str, shape: tuple[int, ...]) -> str:
        own = [f"{prefix}d{j}" for j in range(len(shape))]
        whole.extend(own)
        return " ".join([*batch, *own])

    rule = (
        ", ".join(operand(f"i{i}", s) for i, s in enumerate(env_in))
        + " -> "
        + ", ".join(operand(f"o{i}", s) for i, s in enumerate(env_out))
    )

    def partition(mesh: Any, arg_shapes: Any, result_shape: Any) -> Any:
        q = arg_shapes[qpos]
        local = math.prod(q.sharding.shard_shape(q.shape)[:k])
        shards = max(1, math.prod(q.shape[:k]) // max(1, local))
        per_shard = max(1, threads // shards)

        def lower(*arrays: jax.Array) -> list[jax.Array]:
            return raw(arrays, per_shard)

        arg_shardings = tuple(a.sharding for a in arg_shapes)
        result_shardings = [r.sharding for r in result_shape]
        return mesh, lower, result_shardings, arg_shardings

    op = custom_partitioning(lambda *arrays: raw(arrays, threads))
    op.def_partition(partition=partition, sharding_rule=rule, need_replication_factors=tuple(whole))
    return op


__all__ = [
    "ADVANCED",
    "BAD_WARNINGS",
    "INPUTS",
    "SERIAL_WORK",
    "CEngine",
    "CEngineError",
    "Layout",
    "Unavailable",
    "check_model",
    "layout",
    "path",
]
