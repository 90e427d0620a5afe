"""Throughput of our envs: a batch sweep of the batched env, timed in interleaved rounds.

Everything timed here is a :class:`Runner`: a prepared (compiled, warmed-up) piece of work
whose ``unit()`` advances some envs and returns how many env steps it took. :func:`time_runners`
calibrates how many units make one timed call (about ``target_s`` seconds), then times
every runner in turn, round after round, so that all of them share whatever the machine
is doing at the time (this CPU is shared): a figure is the median over rounds.

Our env is measured in three modes, each a ``lax.scan`` of ``steps`` batched steps with
uniform random actions, jitted once with the state donated:

==============  =========================================================================
``full``        ``BatchedEnv.step``: the env step plus the fresh auto-reset (what agents use)
``functional``  ``vmap(env.step)`` alone: no auto-reset (envs run past their episode end)
``physics``     ``vmap`` of the sim's control step alone (``substeps`` x ``mjx.step``) with
                random controls: no observation, reward, counters or reset. The
                difference to ``functional`` is our task layer's cost.
==============  =========================================================================

For each, the first call (trace + compile + one run) is timed, and the compiled program's
memory (arguments, outputs and temporaries, from XLA's own analysis), the process's peak
resident memory and, on accelerators, the device's peak bytes in use are recorded.

The peers (Gymnasium, EnvPool, MuJoCo's C ``rollout``, gymnax) are runners of the same
kind, prepared by ``benchmarks/peers.py`` of the source checkout (not part of the
package); :mod:`jaxenvs.bench.plot` draws a sweep.
"""

from __future__ import annotations

import dataclasses
import functools
import os
import platform
import resource
import statistics
import time
from collections.abc import Callable, Sequence
from typing import Any, TypeVar

import jax
import jax.numpy as jnp

import jaxenvs
from jaxenvs.actions import random_actions
from jaxenvs.core import BatchedEnv, Env, State
from jaxenvs.core.xla import jit

MODES = ("full", "functional", "physics")

_T = TypeVar("_T")
Step = Callable[[State, jax.Array], State]


@dataclasses.dataclass
class Runner:
    """One prepared measurement.

    Attributes:
      name: who runs (``"jaxenvs"``, ``"envpool"``, ``"mujoco.rollout"``, ...).
      task: the task it stands for (our id; peers are filed under the task they compare to).
      variant: the peer's env id or our mode.
      num_envs: envs advanced together.
      unit: does one unit of work (blocking) and returns the env steps it took.
      info: figures known before timing (first call, memory, threads, ...).
    """

    name: str
    task: str
    variant: str
    num_envs: int
    unit: Callable[[], int]
    info: dict[str, Any] = dataclasses.field(default_factory=dict)


def machine() -> dict[str, Any]:
    """What the numbers were measured on."""
    dev = jax.devices()[0]
    return {
        "host": platform.node(),
        "cpu": platform.processor() or platform.machine(),
        "cpu_count": os.cpu_count(),
        "python": platform.python_version(),
        "jax": jax.__version__,
        "backend": jax.default_backend(),
        "device": dev.device_kind,
        "device_count": jax.device_count(),
    }


def peak_rss_mib() -> float:
    """The process's peak resident memory so far (Linux reports KiB)."""
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024


def device_peak_mib() -> float | None:
    """Peak bytes in use on the first device, where the backend reports it (GPUs)."""
    stats = jax.devices()[0].memory_stats()
    if not stats or "peak_bytes_in_use" not in stats:
        return None
    return float(stats["peak_bytes_in_use"]) / 2**20


# --------------------------------------------------------------------------- our steps
def _physics_step(env: Env) -> Step:
    """The sim's control step alone over a batch, random controls in the actuators' range."""
    sim = env.sim
    lo = jnp.asarray(sim.mj_model.actuator_ctrlrange[:, 0], jnp.float32)
    hi = jnp.asarray(sim.mj_model.actuator_ctrlrange[:, 1], jnp.float32)
    vstep = jax.vmap(sim.step, in_axes=(None, 0, 0))
    model = sim.model_with({})

    def step(state: State, key: jax.Array) -> State:
        n = state.time.shape[0]
        ctrl = jax.random.uniform(key, (n, *lo.shape), minval=lo, maxval=hi)
        return state.replace(data=vstep(model, state.data, ctrl))

    return step


def _one_step(benv: BatchedEnv, mode: str) -> Step:
    """One batched step of ``mode`` with uniform random actions drawn from the key."""
    env, n = benv.env, benv.num_envs
    if mode == "full":
        return lambda state, key: benv.step(state, random_actions(env, key, (n,)))
    if mode == "functional":
        vstep = jax.vmap(env.step, in_axes=(0, 0, None))
        return lambda state, key: vstep(state, random_actions(env, key, (n,)), env.default_params)
    if mode == "physics":
        return _physics_step(env)
    raise ValueError(f"unknown mode {mode!r}; choose from {', '.join(MODES)}")


def _scan_fn(benv: BatchedEnv, mode: str, steps: int) -> Step:
    """``run(state, key) -> state``: ``steps`` steps of ``mode`` in one ``lax.scan``."""
    one = _one_step(benv, mode)

    def run(state: State, key: jax.Array) -> State:
        def body(s: State, k: jax.Array) -> tuple[State, None]:
            return one(s, k), None

        keys = jax.random.split(key, steps)
        state, _ = jax.lax.scan(body, state, keys, unroll=benv.scan_unroll)
        return state

    return run


def _timed(fn: Callable[[], _T]) -> tuple[_T, float]:
    """``fn()`` and the seconds it took."""
    t0 = time.perf_counter()
    out = fn()
    return out, time.perf_counter() - t0


def _engine_info(benv: BatchedEnv, steps: int) -> dict[str, Any]:
    """The figures every runner of ours carries: steps per call, substeps and the engine."""
    info: dict[str, Any] = {"steps_per_call": steps, "substeps": benv.env.sim.substeps}
    info["physics"] = benv.env.physics
    engine = getattr(benv.env.sim, "engine", None)
    if engine is not None:
        info["threads"] = engine.threads
    return info


# --------------------------------------------------------------------------- our runners
def prepare_ours(
    env_id: str,
    num_envs: int,
    mode: str = "full",
    steps: int = 100,
    devices: int | None = None,
    physics: str | None = None,
) -> Runner:
    """Compile and warm up ``steps`` batched steps of ``env_id`` at ``num_envs`` envs.

    ``devices`` > 1 runs the full step through :mod:`jaxenvs.core.sharding` with the batch
    split over that many devices (each timed call then also includes one reset).
    ``physics`` picks the engine (default: the task's ``auto`` choice); the result's
    ``physics`` field names the one used.
    """
    overrides: dict[str, Any] = {} if physics is None else {"physics": physics}
    benv = jaxenvs.make(env_id, num_envs=num_envs, **overrides)
    assert isinstance(benv, BatchedEnv)
    if devices is not None and devices > 1:
        return _prepare_sharded(env_id, benv, mode, steps, devices)
    return prepare_batched(benv, env_id, mode, steps)


def prepare_batched(
    benv: BatchedEnv, task: str, mode: str = "full", steps: int = 100, variant: str | None = None
) -> Runner:
    """:func:`prepare_ours` for an env already built (e.g. with config overrides), on one
    device; the runner is filed under ``task`` with ``variant`` (default: ``mode``)."""
    run = jit(_scan_fn(benv, mode, steps), donate_argnums=0)
    keys = iter(jax.random.split(jax.random.key(0), 1_000_000))

    state, reset_s = _timed(lambda: jax.block_until_ready(jit(benv.reset)(next(keys))))
    lowered, trace_s = _timed(lambda: run.lower(state, next(keys)))
    compiled, compile_s = _timed(lowered.compile)
    state, run_s = _timed(lambda: jax.block_until_ready(compiled(state, next(keys))))
    mem = compiled.memory_analysis()
    xla_mib = (
        None
        if mem is None
        else (mem.argument_size_in_bytes + mem.output_size_in_bytes + mem.temp_size_in_bytes)
        / 2**20
    )
    info: dict[str, Any] = {
        "first_call_s": trace_s + compile_s + run_s,
        "first_reset_s": reset_s,
        "trace_s": trace_s,
        "compile_s": compile_s,
        "xla_memory_mib": xla_mib,
        "devices": benv.devices,
        **_engine_info(benv, steps),
    }
    holder = [state]

    def unit() -> int:
        holder[0] = jax.block_until_ready(compiled(holder[0], next(keys)))
        return benv.num_envs * steps

    return Runner("jaxenvs", task, variant or mode, benv.num_envs, unit, info)


def _prepare_sharded(env_id: str, benv: BatchedEnv, mode: str, steps: int, devices: int) -> Runner:
    from jaxenvs.core import sharding

    if mode != "full":
        raise ValueError("--devices > 1 measures the full (auto-resetting) step only")
    mesh = sharding.make_mesh(devices)
    rollout = sharding.make_sharded_rollout(benv, mesh, steps)
    keys = iter(jax.random.split(jax.random.key(0), 1_000_000))
    _, first_s = _timed(lambda: jax.block_until_ready(rollout(next(keys))))
    info = {
        "first_call_s": first_s,
        "devices": devices,
        "note": "each call includes one reset",
        **_engine_info(benv, steps),
    }

    def unit() -> int:
        jax.block_until_ready(rollout(next(keys)))
        return benv.num_envs * steps

    return Runner("jaxenvs", env_id, mode, benv.num_envs, unit, info)


# --------------------------------------------------------------------------- timing
def time_runners(
    runners: Sequence[Runner],
    repeats: int = 5,
    target_s: float = 0.3,
    log: Callable[[str], None] | None = None,
) -> list[dict[str, Any]]:
    """Time ``runners`` side by side: ``repeats`` rounds, each runner once per round.

    Each runner's call repeats its unit enough times to last about ``target_s`` (from one
    calibration call). Returns one dict per runner with the median env steps/s.
    """
    units = []
    for r in runners:
        _, dt = _timed(r.unit)
        units.append(max(1, min(10_000, round(target_s / max(dt, 1e-6)))))
    rates: list[list[float]] = [[] for _ in runners]
    for i in range(repeats):
        for j, r in enumerate(runners):
            done, dt = _timed(functools.partial(_repeat, r, units[j]))
            rates[j].append(done / dt)
        if log:
            log(f"round {i + 1}/{repeats} done")
    return [_result(r, rs, u) for r, rs, u in zip(runners, rates, units, strict=True)]


def _repeat(runner: Runner, n: int) -> int:
    """``n`` units of ``runner``: the env steps they took."""
    return sum(runner.unit() for _ in range(n))


def _result(runner: Runner, rates: list[float], units: int) -> dict[str, Any]:
    """One runner's figures: the median, least and most env steps/s over the rounds."""
    sps = statistics.median(rates)
    res = {
        "name": runner.name,
        "task": runner.task,
        "variant": runner.variant,
        "num_envs": runner.num_envs,
        "env_steps_per_s": sps,
        "min_env_steps_per_s": min(rates),
        "max_env_steps_per_s": max(rates),
        "units_per_call": units,
        **runner.info,
    }
    if "substeps" in runner.info:
        res["physics_steps_per_s"] = sps * runner.info["substeps"]
    return res


def measure(
    env_id: str,
    num_envs: int,
    steps: int = 100,
    repeats: int = 5,
    mode: str = "full",
) -> dict[str, Any]:
    """Throughput of ``env_id`` at batch ``num_envs`` alone: a dict of figures."""
    runner = prepare_ours(env_id, num_envs, mode, steps)
    res = time_runners([runner], repeats)[0]
    res["peak_rss_mib"] = peak_rss_mib()
    res["device_peak_mib"] = device_peak_mib()
    return res


# --------------------------------------------------------------------------- results
def is_ours(result: dict[str, Any]) -> bool:
    """True for our own results (either engine), False for a peer's."""
    return bool(result["name"] == "jaxenvs")


def best_of(
    results: Sequence[dict[str, Any]], task: str, mode: str = "full", physics: str | None = None
) -> dict | None:
    """Our fastest result for ``task`` in ``mode`` (under ``physics``, or either engine)."""
    ours = [
        r
        for r in results
        if is_ours(r)
        and r["task"] == task
        and r["variant"] == mode
        and physics in (None, r.get("physics", "mjx"))
    ]
    return max(ours, key=lambda r: r["env_steps_per_s"]) if ours else None


def format_table(rows: Sequence[Sequence[Any]]) -> str:
    """Left-aligned text columns."""
    cells = [[str(c) for c in row] for row in rows]
    widths = [max(len(r[i]) for r in cells) for i in range(len(cells[0]))]
    return "\n".join("  ".join(c.ljust(w) for c, w in zip(r, widths, strict=True)) for r in cells)
