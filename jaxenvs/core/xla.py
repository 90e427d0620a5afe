"""How jaxenvs asks XLA to compile its programs: :func:`jit`, ``jax.jit`` with
:data:`COMPILER_OPTIONS`; :func:`jit_once` for a program a run calls once and
:func:`jit_c_engine` for one whose physics is MuJoCo's C engine.

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
machine the main job's cold run ended 1.2 s sooner at the median of five (the figures in
benchmarks/RESULTS.md, "Init compiled without LLVM's optimisations"). The init's results
differ from an optimised compile's in the last bits of its floats, so a run's numbers are
those of another, equally valid start.

A run's training chunk whose physics is MuJoCo's C engine (a native call inside the
program) is compiled on a CPU at LLVM's -O1 (:data:`C_ENGINE_OPTIONS`): XLA compiles only
the policy and the learning around the call, and those chunks ran as fast as at -O2 while
compiling in 20-55% less time (CartPole-v0, Reacher-v0, HexapodJoystick-v0 on 2 cores:
benchmarks/RESULTS.md, "The chunk around the C engine at -O1"). Under MJX the physics is
XLA's code, and Reacher-v0's chunk ran 11% slower at -O1, so MJX's programs keep XLA's
default level.
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
#: what :func:`jit_c_engine` adds on a CPU: LLVM at -O1
C_ENGINE_OPTIONS: Mapping[str, Any] = MappingProxyType({"xla_backend_optimization_level": 1})


def jit(fun: Callable[..., Any], **kwargs: Any) -> Any:
    """``jax.jit(fun, **kwargs)`` compiled with :data:`COMPILER_OPTIONS` (a
    ``compiler_options`` in ``kwargs`` adds to them and wins where both set one); call
    it outermost, as XLA takes options only there."""
    options = {**COMPILER_OPTIONS, **(kwargs.pop("compiler_options", None) or {})}
    return jax.jit(fun, compiler_options=options or None, **kwargs)


def jit_once(fun: Callable[..., Any], **kwargs: Any) -> Any:
    """:func:`jit` for a program a run calls once: where JAX's default backend is a CPU,
    compiled with :data:`ONCE_OPTIONS` too (elsewhere exactly :func:`jit`)."""
    return _on_cpu(ONCE_OPTIONS, fun, kwargs)


def jit_c_engine(fun: Callable[..., Any], physics: str, **kwargs: Any) -> Any:
    """:func:`jit` for a program that steps ``physics``: where that is MuJoCo's C engine
    (``"c"``) and JAX's default backend a CPU, compiled with :data:`C_ENGINE_OPTIONS` too
    (elsewhere exactly :func:`jit`)."""
    return _on_cpu(C_ENGINE_OPTIONS if physics == "c" else {}, fun, kwargs)


def _on_cpu(extra: Mapping[str, Any], fun: Callable[..., Any], kwargs: dict[str, Any]) -> Any:
    """``jit(fun, **kwargs)`` with ``extra`` options added where the backend is a CPU (the
    caller's ``compiler_options`` win where both set one)."""
    if not extra or jax.default_backend() != "cpu":
        return jit(fun, **kwargs)
    options = {**extra, **(kwargs.pop("compiler_options", None) or {})}
    return jit(fun, compiler_options=options, **kwargs)
