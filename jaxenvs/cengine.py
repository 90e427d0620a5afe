"""MuJoCo's C engine behind the functional API (``physics="c"``), for CPUs.

A task's ``reset``/``step`` stay the same pure JAX functions over an ``mjx.Data``; only the
physics step changes. Each control step is one :func:`jax.pure_callback` that hands the
batch's physics state to :class:`mujoco.rollout.Rollout` (MuJoCo's own thread pool, one
``mj_step`` per substep, float64) and writes the result back into the ``mjx.Data``. From
JAX's side it is a pure function: ``jit``, ``vmap`` (nested too: the callback sees every
batch axis at once), ``lax.scan`` and the auto-reset work, and the same inputs give the
same outputs bit for bit whatever the thread count (each env is stepped on its own, from
a state that holds everything ``mj_step`` reads).

What a step writes (:data:`WRITTEN`): ``time``, ``qpos``, ``qvel``, ``act`` and
``actuator_force`` (read back through one ``actuatorfrc`` sensor per actuator that only
the C model has), with the values MuJoCo computes for the same step as ``mjx.step``
(within float32/float64 rounding). What it reads (:data:`READ`): those, ``ctrl`` and the
mocap poses. Every other floating-point field of the state is NaN under this engine, so
a task that reads one (a site position, a contact force) fails its engine-parity test
loudly instead of reading a stale value (``tests/test_cengine.py`` walks every task).

An env whose state is non-finite, or that MuJoCo resets because its state turned bad,
comes back NaN, so the task's divergence check terminates it as under MJX.

The solver warm start (``qacc_warmstart``) is zero at the start of each control step and
carried through its substeps (MuJoCo's rollout takes it in but does not hand it back).

Params: a task's ``sim.model_with(fields)`` names model fields by their MuJoCo names
(``body_mass``, ``actuator_gear``, ...). Under this engine the fields travel to the
callback; unbatched ones are written into the one host model when they change, per-env
ones (domain randomisation) into one model copy per env, only for the envs whose values
changed since the last step (in practice: the envs that were just reset).
"""

from __future__ import annotations

import copy
import functools
import threading
from collections.abc import Mapping
from typing import Any

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
from mujoco import mjx, rollout

_S = mujoco.mjtState
FULLPHYSICS = int(_S.mjSTATE_FULLPHYSICS)
CONTROL = int(_S.mjSTATE_CTRL | _S.mjSTATE_MOCAP_POS | _S.mjSTATE_MOCAP_QUAT)

#: ``mjx.Data`` fields a C step writes.
WRITTEN = ("time", "qpos", "qvel", "act", "actuator_force")
#: ``mjx.Data`` fields a C step reads (and leaves as they are, unless also written).
READ = ("time", "qpos", "qvel", "act", "ctrl", "mocap_pos", "mocap_quat")
#: fields kept at MuJoCo's defaults (applied forces are zero in every task; the rest is
#: empty for the models the C path accepts)
KEPT = ("qfrc_applied", "xfrc_applied", "eq_active", "userdata", "history", "plugin_state")

#: below this many (envs x substeps x dofs) a batch is stepped on the calling thread
SERIAL_WORK = 1024

#: one batch at a time: an engine's scratch MjData and MuJoCo's thread pools are shared by
#: every caller (e.g. the callbacks of several devices running at once)
_POOL_LOCK = threading.Lock()


class CEngineError(ValueError):
    """A model or a params field the C engine cannot step."""


def with_force_sensors(spec: mujoco.MjSpec) -> tuple[mujoco.MjModel, int]:
    """Compile ``spec`` with one ``actuatorfrc`` sensor per actuator appended; returns the
    model and the offset of the first such value in ``sensordata``."""
    model = spec.compile()
    offset = model.nsensordata
    for i, actuator in enumerate(spec.actuators):
        if not actuator.name:
            actuator.name = f"jaxenvs_actuator_{i}"
        spec.add_sensor(
            type=mujoco.mjtSensor.mjSENS_ACTUATORFRC,
            objtype=mujoco.mjtObj.mjOBJ_ACTUATOR,
            objname=actuator.name,
        )
    return (spec.compile() if spec.actuators else model), offset


def nan_data(data: mjx.Data) -> mjx.Data:
    """``data`` with every floating-point field outside READ, WRITTEN and KEPT set to NaN."""
    keep = set(READ) | set(WRITTEN) | set(KEPT)

    def fill(path: Any, leaf: Any) -> Any:
        name = getattr(path[0], "name", "")
        if name in keep or not jnp.issubdtype(jnp.asarray(leaf).dtype, jnp.floating):
            return leaf
        return jnp.full_like(leaf, jnp.nan)

    return jax.tree_util.tree_map_with_path(fill, data)


class CEngine:
    """Steps batches of one model in MuJoCo C from inside JAX programs.

    Args:
      model: the host model to step (timestep and solver options already set), with the
        actuator-force sensors of :func:`with_force_sensors`.
      force_offset: where those sensors start in ``sensordata``.
      threads: the rollout pool's size (``jaxenvs.machine.cpu_threads()``).
    """

    def __init__(self, model: mujoco.MjModel, force_offset: int, threads: int) -> None:
        extra = {
            "history": mujoco.mj_stateSize(model, int(_S.mjSTATE_HISTORY)),
            "plugin state": mujoco.mj_stateSize(model, int(_S.mjSTATE_PLUGIN)),
            "plastic state": mujoco.mj_stateSize(model, int(_S.mjSTATE_PLASTIC)),
        }
        held = [name for name, size in extra.items() if size]
        if held:
            raise CEngineError(f"physics='c' does not step models with {', '.join(held)}")
        if threads < 1:
            raise ValueError(f"threads must be >= 1, got {threads}")
        self.model = model
        self.threads = int(threads)
        self.force_offset = force_offset
        self.nstate = mujoco.mj_stateSize(model, FULLPHYSICS)
        self._pool = rollout.Rollout(nthread=self.threads)
        self._datas = [mujoco.MjData(model) for _ in range(self.threads)]
        self._serial = rollout.Rollout(nthread=0)  # small batches: no thread hand-off
        self._serial_data = [mujoco.MjData(model)]
        self._shared: dict[str, np.ndarray] = {}  # float32 values written into self.model
        self._copies: list[mujoco.MjModel] = []  # per-env models (domain randomisation)
        self._copy_values: dict[str, np.ndarray] = {}

    # ------------------------------------------------------------------ JAX side
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
        """Hold ``ctrl`` for ``substeps`` C physics steps from ``data`` with ``fields``.

        One callback a step, with one packed input (state, control, mocap poses), one
        packed params vector and one packed output: a callback's cost grows with its
        operand count (about 20 us each on the dev CPU, over a fixed ~85 us).
        """
        m = self.model
        dtype = data.qpos.dtype
        ctrl = jnp.asarray(ctrl, data.ctrl.dtype)
        names = tuple(sorted(fields))
        values = []
        for name in names:
            value = jnp.asarray(fields[name], jnp.float32)
            if value.shape != self.field_shape(name):
                raise CEngineError(
                    f"physics='c': params field {name!r} has shape {value.shape}, the "
                    f"model's is {self.field_shape(name)}"
                )
            values.append(value.reshape(-1))
        packed = jnp.concatenate(
            [
                data.time.astype(dtype)[None],
                data.qpos,
                data.qvel,
                data.act.astype(dtype),
                ctrl.astype(dtype),
                data.mocap_pos.reshape(-1).astype(dtype),
                data.mocap_quat.reshape(-1).astype(dtype),
            ]
        )
        params = jnp.concatenate(values) if values else jnp.zeros((0,), jnp.float32)
        sizes = (1, m.nq, m.nv, m.na, m.nu)
        out = jax.ShapeDtypeStruct((sum(sizes),), dtype)
        host = functools.partial(self._host_step, int(substeps), names)
        result = jax.pure_callback(host, out, packed, params, vmap_method="expand_dims")
        time, qpos, qvel, act, force = jnp.split(result, np.cumsum(sizes)[:-1])
        return data.replace(
            time=time[0].astype(data.time.dtype),
            qpos=qpos,
            qvel=qvel,
            act=act.astype(data.act.dtype),
            ctrl=ctrl,
            actuator_force=force.astype(data.actuator_force.dtype),
        )

    # ------------------------------------------------------------------ host side
    def _host_step(
        self, substeps: int, names: tuple[str, ...], packed: np.ndarray, params: np.ndarray
    ) -> np.ndarray:
        m = self.model
        packed, params = np.asarray(packed), np.asarray(params)
        lead = np.broadcast_shapes(packed.shape[:-1], params.shape[:-1])
        batch = int(np.prod(lead, dtype=np.int64))
        if packed.shape[:-1] != lead:
            packed = np.broadcast_to(packed, lead + packed.shape[-1:])
        packed = packed.reshape(batch, -1)
        nphys = 1 + m.nq + m.nv + m.na
        state0 = np.zeros((batch, self.nstate))
        state0[:, :nphys] = packed[:, :nphys]
        control = np.empty((batch, substeps, packed.shape[1] - nphys))
        control[:] = packed[:, None, nphys:]
        models = self._models(names, params, lead, batch)
        if not isinstance(models, list):
            models = [models] * batch
        state = np.empty((batch, substeps, self.nstate))
        sensors = np.empty((batch, substeps, m.nsensordata))
        # a few large jobs per thread (every env costs about the same); batches too small
        # to repay the hand-off to the pool run on the calling thread
        chunk = max(1, batch // (2 * self.threads))
        serial = self.threads == 1 or batch * substeps * m.nv < SERIAL_WORK
        pool, datas = (self._serial, self._serial_data) if serial else (self._pool, self._datas)
        with _POOL_LOCK:
            pool.rollout(
                models,
                datas,
                state0,
                control,
                control_spec=CONTROL,
                skip_checks=True,
                nstep=substeps,
                state=state,
                sensordata=sensors,
                chunk_size=chunk,
            )
        force = sensors[:, -1, self.force_offset : self.force_offset + m.nu]
        result = np.concatenate([state[:, -1, :nphys], force], axis=1).astype(packed.dtype)
        result[self._was_reset(state0, state, substeps), 1 : 1 + m.nq + m.nv] = np.nan
        return result.reshape(lead + result.shape[1:])

    def _was_reset(self, state0: np.ndarray, state: np.ndarray, substeps: int) -> np.ndarray:
        """Which envs MuJoCo reset during the step.

        ``mj_step`` resets a state whose positions, velocities or accelerations are
        non-finite or past ``mjMAXVAL`` to the model's defaults (time 0) and carries on,
        with only a printed warning; MJX keeps stepping the bad state, and the task flags
        it ``info["diverged"]``. Such envs are handed back with NaN positions and
        velocities, so that they are flagged (and, batched, reset) under both engines.
        A reset shows as a bad state going in, or as a clock that went back.
        """
        m = self.model
        nq, nv = m.nq, m.nv
        phys = state0[:, : 1 + nq + nv]
        bad = ~np.all(np.isfinite(phys), axis=1) | np.any(np.abs(phys[:, 1:]) > mujoco.mjMAXVAL, 1)
        dt = m.opt.timestep
        expected = state0[:, :1] + dt * np.arange(1, substeps + 1)
        return bad | np.any(state[:, :, 0] < expected - 0.5 * dt, axis=1)

    def _models(
        self, names: tuple[str, ...], params: np.ndarray, lead: tuple, batch: int
    ) -> mujoco.MjModel | list[mujoco.MjModel]:
        """The model(s) to step: the shared one, or one per env when params are per-env."""
        shapes, bounds = self._layout(names)
        if params.size == bounds[-1]:
            flat = params.reshape(-1)
            for i, (name, shape) in enumerate(zip(names, shapes, strict=True)):
                value = flat[bounds[i] : bounds[i + 1]].reshape(shape)
                known = self._shared.get(name)
                if known is None:
                    known = self._shared[name] = getattr(self.model, name).astype(np.float32)
                if value.tobytes() != known.tobytes():
                    getattr(self.model, name)[...] = value
                    self._shared[name] = value.copy()
            return self.model
        self._grow(names, batch)
        per_env = np.broadcast_to(params, lead + params.shape[-1:]).reshape(batch, -1)
        for i, (name, shape) in enumerate(zip(names, shapes, strict=True)):
            value = per_env[:, bounds[i] : bounds[i + 1]].reshape(batch, *shape)
            known = self._copy_values[name][:batch]
            changed = np.flatnonzero(np.any((value != known).reshape(batch, -1), axis=1))
            for j in changed:
                getattr(self._copies[j], name)[...] = value[j]
            known[changed] = value[changed]
        return self._copies[:batch]

    @functools.lru_cache(maxsize=16)  # noqa: B019 - one engine per Sim, kept for its life
    def _layout(self, names: tuple[str, ...]) -> tuple[list[tuple[int, ...]], list[int]]:
        """Shapes of the packed params fields and their bounds in the packed vector."""
        shapes = [self.field_shape(n) for n in names]
        return shapes, [int(b) for b in np.cumsum([0] + [int(np.prod(sh)) for sh in shapes])]

    def _grow(self, names: tuple[str, ...], batch: int) -> None:
        have = len(self._copies)
        if have >= batch and all(n in self._copy_values for n in names):
            return
        for _ in range(have, batch):
            self._copies.append(copy.copy(self.model))
        for name in names:
            old = self._copy_values.get(name)
            rows = [getattr(c, name).astype(np.float32) for c in self._copies]
            new = np.stack(rows)
            if old is not None:
                new[: len(old)] = old
            self._copy_values[name] = new
