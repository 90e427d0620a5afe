"""The engine rule: which engine ``physics="auto"`` (and every other value) means.

:func:`resolve_engine` is the one place that turns a task config's ``physics`` into the
engine that steps it, ``"mjx"`` or ``"c"``. It is called once, when an env is made:
:func:`jaxenvs.make` calls it with the batch size (through :func:`with_engine`), the
runner with its ``num_envs`` (:func:`jaxenvs.run.run_config.engine_resolved`), and
:class:`jaxenvs.core.Env` itself for a config built without either; a built env's config
holds the resolved engine, so resolving it again returns it unchanged.

The rule's inputs are two of the task's engine figures (one table,
:mod:`jaxenvs.physics.figures`), both measured (the evidence: benchmarks/RESULTS.md,
section "physics='auto' on a CPU", from ``benchmarks/engines_sweep.sh``):

* ``cpu_physics``: the engine a CPU steps the task with (``"mjx"`` unless measured);
* ``cpu_mjx_from``: the envs per CPU device from which MJX's steady-state throughput
  passed the C engine's (``None``: never). The rule compares the batch with
  ``cpu_mjx_from`` times the CPU backend's device count (``jax.local_device_count("cpu")``:
  one per two cores once :func:`jaxenvs.machine.use_cores` or a command has set it up, one
  otherwise): MJX spreads a batch over every device, each running its own slice's
  program, while a C batch below 512 envs a device stays whole on one device with every
  engine thread. No built-in task has a cross-over today: since the C engine steps on
  XLA's own thread pool, C led MJX for every task at every swept size on 2 and 16 cores.
"""

from __future__ import annotations

import dataclasses
from typing import Any, TypeVar

import jax

from jaxenvs.physics.figures import EngineFigures, figures_for

#: values of ``TaskConfig.physics``
PHYSICS_CHOICES = ("auto", "mjx", "c")

ConfigT = TypeVar("ConfigT")


def resolve_engine(
    task: type,
    requested: str,
    num_envs: int | None = None,
    backend: str | None = None,
    cpu_devices: int | None = None,
) -> str:
    """The engine, ``"mjx"`` or ``"c"``, that ``requested`` means for ``task`` (an
    :class:`jaxenvs.core.Env` subclass) in a batch of ``num_envs`` (``None``: one env) on
    ``backend`` (default: JAX's default backend) with ``cpu_devices`` CPU devices
    (default: the CPU backend's; a record of another machine passes its own).

    ``"auto"`` is MJX on an accelerator; on a CPU it is the task's ``cpu_physics``, or MJX
    for batches of at least its ``cpu_mjx_from`` envs per CPU device (``cpu_mjx_from x
    cpu_devices``). ``"mjx"`` and ``"c"`` mean themselves,
    except that ``"c"`` on an accelerator raises ``ValueError`` (MuJoCo's C engine runs on
    the CPU only); any other value raises ``ValueError``.
    """
    if requested not in PHYSICS_CHOICES:
        raise ValueError(f"physics must be one of {', '.join(PHYSICS_CHOICES)}, got {requested!r}")
    backend = backend or jax.default_backend()
    if requested == "auto":
        if backend != "cpu":
            return "mjx"
        figures = figures_for(task)
        per_device = figures.cpu_mjx_from
        if per_device is not None and num_envs is not None:
            devices = jax.local_device_count("cpu") if cpu_devices is None else cpu_devices
            if num_envs >= per_device * devices:
                return "mjx"
        return figures.cpu_physics
    if requested == "c" and backend != "cpu":
        raise ValueError(
            f"physics='c' steps MuJoCo's C engine on the CPU, but JAX's default backend is "
            f"{backend!r}: use physics='mjx' or 'auto' there, or run with JAX_PLATFORMS=cpu"
        )
    return requested


def with_engine(factory: Any, config: ConfigT, num_envs: int | None = None) -> ConfigT:
    """``config`` with its ``physics`` resolved by :func:`resolve_engine` for a batch of
    ``num_envs`` envs of ``factory``'s task.

    Only a task class carries the rule's inputs: for a factory function ``config`` comes
    back as it is, and the env it builds resolves its own engine (for one env).
    """
    requested = getattr(config, "physics", None)
    if not isinstance(factory, type) or requested is None:
        return config
    engine = resolve_engine(factory, requested, num_envs)
    if engine == requested:
        return config
    return dataclasses.replace(config, physics=engine)  # type: ignore[type-var]


__all__ = ["PHYSICS_CHOICES", "EngineFigures", "figures_for", "resolve_engine", "with_engine"]
