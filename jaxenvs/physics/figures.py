"""The per-task engine figures: one table, measured (benchmarks/RESULTS.md, "physics='auto'
on a CPU" and "The C engine over the host devices"; benchmarks/engines_sweep.sh).

:func:`figures_for` is what the engine rule (:func:`jaxenvs.physics.resolve_engine`) and
the plan (:func:`jaxenvs.core.plan.plan`) read. A task not in :data:`FIGURES` (a user's)
states its own with a class attribute ``engine_figures`` (an :class:`EngineFigures`), or
gets the defaults: MJX on every backend.
"""

from __future__ import annotations

import dataclasses

#: the fewest envs a device steps in a C batch spread by default: on a 16-core host (8
#: devices) a C batch of 16 or 256 envs split eight ways stepped 2.2-2.3x slower than the
#: same batch on one device (benchmarks/NOTES.md, "The C engine over the host devices")
C_ENVS_PER_DEVICE = 512


@dataclasses.dataclass(frozen=True)
class EngineFigures:
    """How a task is best stepped on a CPU.

    Attributes:
      cpu_physics: the engine ``physics="auto"`` picks on a CPU (``"mjx"`` unless the
        task's engine parity and speed were measured).
      cpu_mjx_from: the envs per CPU device from which MJX's steady-state throughput
        passed the C engine's (``None``: never).
      c_envs_per_device: under the C engine, the fewest envs a host device steps when a
        batch spreads over the CPU's devices by default; ``None``: a C batch stays on one
        device, stepped by every engine thread (a step that is mostly contact physics
        scales better on one device's engine pool).
    """

    cpu_physics: str = "mjx"
    cpu_mjx_from: int | None = None
    c_envs_per_device: int | None = C_ENVS_PER_DEVICE


#: the built-in tasks' figures, by task class name (a subclass inherits its base's)
FIGURES: dict[str, EngineFigures] = {
    # the cartpole tasks and the reacher: C led MJX at every swept size on 2 and 16 cores
    "_CartpoleTask": EngineFigures(cpu_physics="c"),
    "Reacher": EngineFigures(cpu_physics="c"),
    # the hexapod: contact physics, one device's engine pool (NOTES)
    "HexapodTask": EngineFigures(cpu_physics="c", c_envs_per_device=None),
    "HexapodOneLeg": EngineFigures(cpu_physics="c", c_envs_per_device=None),
}


def figures_for(task: type) -> EngineFigures:
    """The figures of the task class ``task``: its own ``engine_figures`` attribute, else
    the :data:`FIGURES` row of the nearest class in its MRO, else the defaults."""
    own = getattr(task, "engine_figures", None)
    if isinstance(own, EngineFigures):
        return own
    for cls in getattr(task, "__mro__", ()):
        if cls.__name__ in FIGURES and cls.__module__.startswith("jaxenvs."):
            return FIGURES[cls.__name__]
    return EngineFigures()
