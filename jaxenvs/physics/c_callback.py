"""The C engine's Python callback path (:mod:`jaxenvs.physics.cengine`): the native
engine's contract over ``mujoco.batch.Batch``, where the native part cannot be built or
loaded."""

from __future__ import annotations

import threading
from collections.abc import Sequence
from typing import Any

import mujoco
import numpy as np

from jaxenvs.physics.c_layout import BAD_WARNINGS, SERIAL_WORK, Layout


class Callback:
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
