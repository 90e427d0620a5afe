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

import dataclasses
import functools
import math
import threading
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

if TYPE_CHECKING:
    from mujoco import mjx

_S = mujoco.mjtState
_W = mujoco.mjtWarning

#: ``mjx.Data`` fields a C step reads
INPUTS = (
    "time",
    "qpos",
    "qvel",
    "act",
    "qacc_warmstart",
    "ctrl",
    "qfrc_applied",
    "xfrc_applied",
    "eq_active",
    "mocap_pos",
    "mocap_quat",
    "userdata",
)
#: the state a C step advances (inputs that are also outputs)
ADVANCED = ("time", "qpos", "qvel", "act", "qacc_warmstart")
#: warnings that mark a step as failed (see the module docstring)
BAD_WARNINGS = tuple(
    int(w)
    for w in (
        _W.mjWARN_CONTACTFULL,
        _W.mjWARN_CNSTRFULL,
        _W.mjWARN_BADQPOS,
        _W.mjWARN_BADQVEL,
        _W.mjWARN_BADQACC,
        _W.mjWARN_BADCTRL,
    )
)
#: below this many (envs x substeps x dofs) a batch is stepped on the calling thread (a
#: hand-off to the pool costs about as much as 64 dof-steps of a small model)
SERIAL_WORK = 64


class CEngineError(ValueError):
    """A model, a params field or a state field the C engine cannot step or provide."""


class Unavailable:
    """Stands in for an ``mjx.Data`` field the C engine does not provide.

    A pytree node with no leaves, so states holding it are jitted, vmapped, scanned and
    merged as usual; any use of it as a value (an attribute, an index, arithmetic,
    ``jnp.asarray``) raises :class:`CEngineError` naming the field.
    """

    __slots__ = ("name", "why")

    def __init__(self, name: str, why: str = "layout") -> None:
        object.__setattr__(self, "name", name)
        #: ``"layout"`` (the C engine has no such field) or ``"undeclared"`` (the task's
        #: ``derived_fields`` leave it out, so the engine does not write it)
        object.__setattr__(self, "why", why)

    def fail(self) -> Any:
        if self.why == "undeclared":
            raise CEngineError(
                f"mjx.Data field {self.name!r} is not written by physics='c' for this task: "
                "add it to the task's derived_fields (the derived fields it reads)"
            )
        raise CEngineError(
            f"mjx.Data field {self.name!r} is not provided by physics='c' (MuJoCo C lays "
            "out contacts and constraints differently from MJX): read it under "
            "physics='mjx'"
        )

    def __getattr__(self, attr: str) -> Any:
        if attr.startswith("__"):
            raise AttributeError(attr)
        return self.fail()

    def __setattr__(self, attr: str, value: Any) -> None:
        self.fail()

    def __jax_array__(self) -> Any:
        return self.fail()

    def __array__(self, *args: Any, **kwargs: Any) -> Any:
        return self.fail()

    def __getitem__(self, key: Any) -> Any:
        return self.fail()

    def __bool__(self) -> bool:
        return bool(self.fail())

    def __len__(self) -> int:
        return int(self.fail())

    def __repr__(self) -> str:
        return f"Unavailable({self.name!r}: not provided by physics='c', {self.why})"

    def __eq__(self, other: object) -> bool:
        return isinstance(other, Unavailable) and (other.name, other.why) == (self.name, self.why)

    def __hash__(self) -> int:
        return hash(("jaxenvs.physics.cengine.Unavailable", self.name, self.why))


def _fail_op(self: Unavailable, *args: Any) -> Any:
    return self.fail()


for _op in ("add", "sub", "mul", "truediv", "floordiv", "pow", "matmul", "mod"):
    setattr(Unavailable, f"__{_op}__", _fail_op)
    setattr(Unavailable, f"__r{_op}__", _fail_op)
for _op in ("neg", "pos", "abs", "lt", "le", "gt", "ge", "float", "int", "iter"):
    setattr(Unavailable, f"__{_op}__", _fail_op)

jax.tree_util.register_pytree_node(
    Unavailable, lambda u: ((), (u.name, u.why)), lambda aux, _: Unavailable(*aux)
)


@dataclasses.dataclass(frozen=True)
class Layout:
    """Which ``mjx.Data`` fields a C step reads and writes, for one model.

    Attributes:
      inputs: non-empty :data:`INPUTS` fields, in call order.
      outputs: ``(name, in_impl)`` of every field written (``in_impl``: a field of
        ``data._impl``), :data:`ADVANCED` first.
      unavailable: ``data._impl`` fields the C engine does not provide.
      shapes: each input's and output's shape for one env.
      skipped: ``(name, in_impl)`` of the derived fields it provides but does not write
        (those a task's ``derived_fields`` leave out).
    """

    inputs: tuple[str, ...]
    outputs: tuple[tuple[str, bool], ...]
    unavailable: tuple[str, ...]
    shapes: Mapping[str, tuple[int, ...]]
    skipped: tuple[tuple[str, bool], ...] = ()


def layout(
    model: mujoco.MjModel, template: mjx.Data, derived: Sequence[str] | None = None
) -> Layout:
    """The :class:`Layout` of ``model`` for an ``mjx.Data`` shaped like ``template``,
    writing every derived field it provides, or only those named in ``derived``."""
    if isinstance(derived, str):
        raise TypeError(
            f"derived_fields must be a tuple of field names, not the string {derived!r}"
        )
    c_data = mujoco.MjData(model)
    inputs: list[str] = []
    outputs: list[tuple[str, bool]] = [(n, False) for n in ADVANCED]
    unavailable: list[str] = []
    skipped: list[tuple[str, bool]] = []

    def write(name: str, in_impl: bool) -> None:
        (outputs if derived is None or name in derived else skipped).append((name, in_impl))

    shapes: dict[str, tuple[int, ...]] = {}

    def matches(name: str, leaf: Any) -> bool:
        if name == "actuator_moment":  # MJX dense (nu, nv); MuJoCo compressed rows
            return leaf.shape == (model.nu, model.nv)
        value = getattr(c_data, name, None)
        return (
            isinstance(value, np.ndarray)
            and value.dtype == np.float64
            and value.size == np.size(leaf)
            and jnp.issubdtype(leaf.dtype, jnp.floating)
        )

    for field in dataclasses.fields(template):
        name = field.name
        if name == "_impl":
            continue
        leaf = getattr(template, name)
        shapes[name] = np.shape(leaf)
        if name in INPUTS:
            if np.size(leaf) or name == "time":
                inputs.append(name)
        elif name not in ADVANCED and np.size(leaf) and matches(name, leaf):
            write(name, False)
        elif np.size(leaf) and name not in ("history", "plugin_state"):
            raise CEngineError(f"physics='c' has no value for mjx.Data field {name!r}")
    impl = template._impl
    for field in dataclasses.fields(impl):
        name = field.name
        leaf = getattr(impl, name)
        if isinstance(leaf, int | float | np.integer):  # sizes (ncon, nefc, ...)
            continue
        if isinstance(leaf, jax.Array | np.ndarray):
            shapes[name] = np.shape(leaf)
            if not np.size(leaf):
                continue
            if matches(name, leaf):
                write(name, True)
                continue
        unavailable.append(name)
    empty = {n for n, shape in shapes.items() if not math.prod(shape)}  # nothing to write
    known = {n for n, _ in outputs + skipped} | set(INPUTS) | empty
    unknown = sorted(set(derived or ()) - known)
    if unknown:
        raise CEngineError(
            f"derived_fields: {', '.join(unknown)} not among the mjx.Data fields "
            "physics='c' provides for this model"
        )
    return Layout(tuple(inputs), tuple(outputs), tuple(unavailable), shapes, tuple(skipped))


def check_model(model: mujoco.MjModel) -> None:
    """Raise :class:`CEngineError` for a model the C engine cannot step from an
    ``mjx.Data`` (state it does not carry: history, plugin state, plasticity)."""
    extra = {
        "history": int(_S.mjSTATE_HISTORY),
        "plugin state": int(_S.mjSTATE_PLUGIN),
        "plastic state": int(_S.mjSTATE_PLASTIC),
    }
    held = [name for name, spec in extra.items() if mujoco.mj_stateSize(model, spec)]
    if held:
        raise CEngineError(f"physics='c' does not step models with {', '.join(held)}")


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
        self._callback: _Callback | None = None
        if self.path == "native":
            self.key = native.register_model(model)
        else:
            if via is None:
                _warn_fallback_once()
            self._callback = _Callback(model, self.threads, self.layout)

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


class _Callback:
    """The callback path: the native engine's contract over ``mujoco.batch.Batch``.

    One persistent batch (an ``MjData`` per env) per batch size, so that every derived
    field is the env's own, as in the native engine, which clears them before each step.
    """

    def __init__(self, model: mujoco.MjModel, threads: int, lay: Layout) -> None:
        self.model = model
        self.threads = threads
        self.layout = lay
        # (batch, the model fields it has expanded) per (batch size, threads)
        self._batches: dict[tuple[int, int], tuple[Any, set[str]]] = {}
        self._lock = threading.Lock()  # devices may call at once; the batches are shared

    def _batch(self, nsim: int, threads: int) -> tuple[Any, set[str]]:
        from mujoco import batch

        key = (nsim, threads)
        if key not in self._batches:
            self._batches[key] = (batch.Batch(self.model, nsim, threads, persistent=True), set())
        return self._batches[key]

    def __call__(
        self, substeps: int, names: Sequence[str], threads: int, *arrays: Any
    ) -> list[np.ndarray]:
        with self._lock:
            return self._step(substeps, names, threads, *arrays)

    def _step(
        self, substeps: int, names: Sequence[str], threads: int, *arrays: Any
    ) -> list[np.ndarray]:
        from mujoco import batch as batch_module

        m, lay = self.model, self.layout
        arrays_np = [np.asarray(a) for a in arrays]
        ins, params = arrays_np[: len(lay.inputs)], arrays_np[len(lay.inputs) :]
        qpos = ins[lay.inputs.index("qpos")]
        lead = qpos.shape[: qpos.ndim - 1]
        nsim = int(np.prod(lead, dtype=np.int64))
        serial = threads == 1 or nsim * max(substeps, 1) * max(m.nv, 1) < SERIAL_WORK
        b, expanded = self._batch(nsim, 1 if serial else threads)
        for name, value in zip(lay.inputs, ins, strict=True):
            view = b.bind(name)
            view[...] = value.reshape(view.shape)
        for name in expanded - set(names):
            b.expand(name)[...] = getattr(m, name)
        for name, value in zip(names, params, strict=True):
            rows = b.expand(name)
            rows[...] = value.reshape(rows.shape)
            expanded.add(name)
        time0 = b.bind("time").copy()
        b.warning[:, list(BAD_WARNINGS), 1] = 1
        try:
            if substeps:
                b.step(None, substeps)
            else:
                b.forward(None)
        except batch_module.SimulationError:
            pass
        bad = (b.status != 0) | np.any(b.warning[:, list(BAD_WARNINGS), 1] != 1, axis=1)
        out = []
        for name, _ in lay.outputs:
            if name == "actuator_moment":
                value = _dense_moment(b, m)
            else:
                value = np.array(b.bind(name), dtype=np.float64)
            flat = value.reshape(nsim, -1)
            if name == "time":
                flat[bad, 0] = time0[bad] + substeps * m.opt.timestep
            else:
                flat[bad] = np.nan
            out.append(flat.reshape(lead + lay.shapes[name]).astype(qpos.dtype))
        return out


def _dense_moment(b: Any, m: mujoco.MjModel) -> np.ndarray:
    """MuJoCo's compressed-row ``actuator_moment`` of each sim as MJX's dense (nu, nv)."""
    nnz, adr = b.bind("moment_rownnz"), b.bind("moment_rowadr")
    col, val = b.bind("moment_colind"), b.bind("actuator_moment")
    dense = np.zeros((b.nsim, m.nu, m.nv))
    for j in range(int(nnz.max(initial=0))):
        valid = nnz > j
        k = np.where(valid, adr + j, 0)
        cols = np.take_along_axis(col, k, axis=1)
        vals = np.take_along_axis(val, k, axis=1)
        sims, acts = np.nonzero(valid)
        dense[sims, acts, cols[valid]] = vals[valid]
    return dense
