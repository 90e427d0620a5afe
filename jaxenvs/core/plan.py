"""The plan: how a batch of envs runs, decided once.

:func:`plan` decides, when an env or a run is made, the engine that steps the task
(:func:`jaxenvs.physics.resolve_engine`, from the task's figures in
:mod:`jaxenvs.physics.figures`), the backend, the devices the batch spreads over
(:func:`jaxenvs.core.placement.batch_devices`) and how an auto-reset computes its fresh
starts. The env, the batch (:class:`jaxenvs.core.BatchedEnv`) and the run carry the
:class:`Plan`; nothing reads the backend or the device count again at step time.

**One auto-reset.** A batch over several devices steps as a program per device
(:func:`jaxenvs.core.placement.per_device`, a ``shard_map``) on every backend: each device
steps its slice and resets its own finished envs, with no cross-device reduction a step.
Within a device the fresh starts are computed ``"compact"`` (for the finished envs alone,
in chunks, as often as the device's own count needs: on a CPU from
:data:`COMPACT_RESET_FROM` envs a device, outside a ``vmap`` over seeds) or ``"whole"``
(for every env of the device when any finished: on accelerators, small batches and a
batch under ``vmap``, where a data-dependent loop would run as long as the longest). Each
env's fresh start depends on its own key, params and carry only, so the states are the
same bit for bit every way.
"""

from __future__ import annotations

import dataclasses

import jax
from jax.sharding import Mesh

from jaxenvs.core import placement
from jaxenvs.physics import resolve_engine
from jaxenvs.physics.figures import figures_for

#: a device's share of the batch from which a CPU step resets only its finished envs
#: (benchmarks/NOTES.md, "A compact auto-reset, and the walker's C batch on one device")
COMPACT_RESET_FROM = 64

#: the values of :attr:`Plan.reset`
RESET_MODES = ("compact", "whole")


@dataclasses.dataclass(frozen=True)
class Plan:
    """How a batch runs (see the module docstring).

    Attributes:
      physics: the engine, ``"mjx"`` or ``"c"``.
      backend: JAX's backend the batch runs on (``"cpu"``, ``"gpu"``, ``"tpu"``).
      devices: the local devices the batch's env axis is split over (1: none).
      reset: ``"compact"`` or ``"whole"`` (:data:`RESET_MODES`).
    """

    physics: str
    backend: str
    devices: int = 1
    reset: str = "whole"

    def __post_init__(self) -> None:
        if self.reset not in RESET_MODES:
            raise ValueError(f"reset must be one of {RESET_MODES}, got {self.reset!r}")
        if self.devices < 1:
            raise ValueError(f"devices must be >= 1, got {self.devices}")

    @property
    def mesh(self) -> Mesh | None:
        """The 1-D mesh over the plan's devices (:func:`placement.local_mesh`); ``None``
        on one device."""
        return placement.local_mesh(self.devices)

    def reset_slots(self, per_device: int) -> int:
        """Fresh starts a step computes per device: an eighth of the device's envs under
        the compact reset, 0 for "every env of the device when any finished"."""
        return per_device // 8 if self.reset == "compact" else 0


def plan(
    task: type,
    physics: str = "auto",
    num_envs: int | None = None,
    devices: int | None = None,
    *,
    vmapped: bool = False,
    backend: str | None = None,
) -> Plan:
    """The plan of ``num_envs`` envs (``None``: one env) of the task class ``task`` asking
    for ``physics`` on ``devices`` devices (``None``: the default spread,
    :func:`placement.batch_devices`), on ``backend`` (default: JAX's default backend).
    ``vmapped``: the batch is stepped under a ``vmap`` (a trainer's seeds), so its reset is
    ``"whole"``.

    A command that must run on the CPU (a robot host, a renderer) asks for
    ``backend="cpu"``; ``physics="c"`` on an accelerator raises ``ValueError``."""
    backend = backend or jax.default_backend()
    engine = resolve_engine(task, physics, num_envs, backend)
    if num_envs is None:
        return Plan(engine, backend)
    n = placement.batch_devices(num_envs, devices, engine, figures_for(task).c_envs_per_device)
    compact = backend == "cpu" and not vmapped and num_envs // n >= COMPACT_RESET_FROM
    return Plan(engine, backend, n, "compact" if compact else "whole")
