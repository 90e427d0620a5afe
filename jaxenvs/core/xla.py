"""How jaxenvs asks XLA to compile its programs: :func:`jit`, ``jax.jit`` with
:data:`COMPILER_OPTIONS`, and :func:`jit_once` for a program a run calls once.

On a CPU, XLA's MLIR fusion emitters (its default) cost more compile time and memory on
our programs than its LLVM loop emitters, for the same or better speed: the options pick
the loop emitters. XLA takes that option from jax 0.6 (the oldest the package installs
with) to 0.10; from 0.11 it compiles with the fusion emitters only and refuses the
option, so there the options are empty and jaxenvs compiles with XLA's defaults. They are
per program (``jax.jit``'s ``compiler_options``), so they change no program but the ones
compiled with them, and XLA takes them only on the outermost ``jax.jit`` (a function
traced inside another is compiled with its caller's). Measured side by side, with the
commands, in benchmarks/RESULTS.md ("XLA's loop emitters on a CPU"). Every program
jaxenvs compiles goes through :func:`jit`, but for a batch spread over several devices
whose ``reset`` or ``step`` is called outside any ``jit`` (its own plain ``jax.jit``,
which is meant to be traced inside its caller's); jit a jaxenvs env yourself with it (or
pass ``compiler_options=dict(COMPILER_OPTIONS)``) to get the same programs::

    import jaxenvs.machine
    step = jaxenvs.machine.jit(benv.step, donate_argnums=0)

A program that runs once per run (a run's init: the networks' initialisers and the first
reset) is compiled on a CPU with LLVM's optimisations off as well (:data:`ONCE_OPTIONS`):
its compile is on the critical path of every cold run and its run is not. On the 2-core
machine init's compile went from 1.4 s to 0.3 s; the main job's cold run ended 1.2 s
sooner at the median of five rounds in one process each, and 0.7 s (0.3 s between the
medians) in the benchmark's five rounds against SB3 (benchmarks/RESULTS.md, "Init compiled
without LLVM's optimisations"). The init's results differ from an optimised compile's in
the last bits of its floats, so a run's numbers are those of another, equally valid start.
The level is the program's own option, so it wins over an ``XLA_FLAGS`` setting of
``--xla_backend_optimization_level`` for the init.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from types import MappingProxyType
from typing import Any

import jax

#: XLA options for every program jaxenvs compiles (read when :func:`jit` is called)
COMPILER_OPTIONS: Mapping[str, Any] = MappingProxyType(
    {"xla_cpu_use_fusion_emitters": False} if jax.__version_info__ < (0, 11) else {}
)
#: what :func:`jit_once` adds on a CPU: LLVM at -O0
ONCE_OPTIONS: Mapping[str, Any] = MappingProxyType({"xla_backend_optimization_level": 0})


def jit(fun: Callable[..., Any], **kwargs: Any) -> Any:
    """``jax.jit(fun, **kwargs)`` compiled with :data:`COMPILER_OPTIONS` (a
    ``compiler_options`` in ``kwargs`` adds to them and wins where both set one); call
    it outermost, as XLA takes options only there."""
    options = {**COMPILER_OPTIONS, **(kwargs.pop("compiler_options", None) or {})}
    return jax.jit(fun, compiler_options=options or None, **kwargs)


def jit_once(fun: Callable[..., Any], **kwargs: Any) -> Any:
    """:func:`jit` for a program a run calls once: where JAX's default backend is a CPU
    when it is called (the program is wrapped, not yet compiled), compiled with
    :data:`ONCE_OPTIONS` too (elsewhere exactly :func:`jit`)."""
    if jax.default_backend() == "cpu":
        kwargs["compiler_options"] = {**ONCE_OPTIONS, **(kwargs.get("compiler_options") or {})}
    return jit(fun, **kwargs)
