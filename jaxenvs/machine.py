"""How much of the machine jaxenvs uses: one knob, the number of CPU cores.

Two mechanisms use the CPU's cores, and both read this module:

* **MJX on a CPU** runs one XLA program per host device, and one XLA CPU device keeps
  about two cores busy whatever the machine has (benchmarks/RESULTS.md). jaxenvs therefore
  asks XLA for ``cores // 2`` host devices (at least 1) and spreads env batches over them
  (:mod:`jaxenvs.core.placement`), under either engine. On a 2-core machine that is one device.
* **MuJoCo's C engine** (``physics="c"``, :mod:`jaxenvs.physics.cengine`) steps a batch with a pool
  of ``cores`` threads; a batch spread over the host devices gives each device's call its
  share, ``cores // devices``.

``cores`` defaults to the cores this process may run on (``os.sched_getaffinity``).
:func:`use_cores` changes it; the command line calls it with ``--threads`` before JAX
starts. The XLA device count can only be set before JAX initialises its backends (the
first JAX operation), so library users who want it call :func:`use_cores` first thing::

    import jaxenvs
    jaxenvs.machine.use_cores()        # all usable cores; or use_cores(8)

A choice the user already made wins: ``XLA_FLAGS=--xla_force_host_platform_device_count``,
``JAX_NUM_CPU_DEVICES`` or ``jax.config.update("jax_num_cpu_devices", n)``.

**How jaxenvs compiles.** Every program jaxenvs compiles goes through :func:`jit`
(``jax.jit`` with :data:`COMPILER_OPTIONS`: on a CPU, XLA's loop emitters, for less
compile time and memory; :mod:`jaxenvs.core.xla`). Jit an env yourself the same way::

    step = jaxenvs.machine.jit(benv.step, donate_argnums=0)
"""

from __future__ import annotations

import os
from typing import Any

import jax

from jaxenvs.core import placement
from jaxenvs.core.xla import COMPILER_OPTIONS, jit

__all__ = [
    "COMPILER_OPTIONS",
    "cores",
    "cpu_threads",
    "describe",
    "jit",
    "usable_cores",
    "use_cores",
]

_cores: int | None = None


def usable_cores() -> int:
    """The CPU cores this process may run on."""
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:  # not on Linux
        return os.cpu_count() or 1


def cores() -> int:
    """The cores jaxenvs uses: set by :func:`use_cores`, else :func:`usable_cores`."""
    return _cores if _cores is not None else usable_cores()


def cpu_threads() -> int:
    """The most threads a C engine call steps its envs with (:func:`cores`)."""
    return cores()


def use_cores(n: int | None = None, *, strict: bool = True) -> int:
    """Use ``n`` CPU cores (default: all usable) for MJX's host devices and C's threads.

    Call it before the first JAX operation: the host device count is fixed when JAX
    starts its backends. Called later, the thread count still changes, and ``strict``
    decides whether the fixed device count raises (``RuntimeError`` naming the fix) or
    only warns. Returns the number of cores now in use.
    """
    global _cores
    if n is not None and (isinstance(n, bool) or not isinstance(n, int) or n < 1):
        raise ValueError(f"cores must be a positive integer, got {n!r}")
    _cores = n
    placement.set_host_devices(placement.host_devices_for(cores()), strict=strict)
    return cores()


def describe(env: Any) -> str:
    """One line naming the engine an env steps with (printed when a command starts)."""
    if getattr(env, "physics", "mjx") == "c":
        return f"physics: c (MuJoCo C on the CPU, {env.sim.engine.threads} threads)"
    return f"physics: mjx ({jax.default_backend()}, {jax.local_device_count()} device(s))"
