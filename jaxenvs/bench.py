"""Throughput measurement: our envs over a batch sweep, and the peers beside them.

Everything timed here is a :class:`Runner`: a prepared (compiled, warmed-up) piece of work
whose ``unit()`` advances some envs and returns how many env steps it took. :func:`time_runners`
calibrates how many units make one timed call (about ``target_s`` seconds), then times
every runner in turn, round after round, so that ours and the peers share whatever the
machine is doing at the time (this CPU is shared): a figure is the median over rounds.

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

Peers (:func:`peer_runners`) are optional imports; one that is missing is returned as a
:class:`Skipped` with the reason, never dropped.
"""

from __future__ import annotations

import dataclasses
import os
import platform
import resource
import statistics
import time
from collections.abc import Callable, Sequence
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

import jaxenvs
from jaxenvs import files
from jaxenvs.actions import random_actions
from jaxenvs.core import BatchedEnv, Env, State

MODES = ("full", "functional", "physics")

#: peers of each of our tasks: (Gymnasium id, EnvPool id).
PEER_IDS: dict[str, tuple[str, str]] = {
    "CartPole-v0": ("CartPole-v1", "CartPole-v1"),
    "Reacher-v0": ("Reacher-v5", "Reacher-v4"),
    "HexapodWalk-v0": ("Ant-v5", "Ant-v4"),
}


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


@dataclasses.dataclass(frozen=True)
class Skipped:
    """A peer that could not run here, and why."""

    name: str
    task: str
    variant: str
    reason: str

    def as_dict(self) -> dict[str, Any]:
        return {**dataclasses.asdict(self), "skipped": True}


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


# --------------------------------------------------------------------------- ours
def _physics_step(env: Env) -> Callable[[State, jax.Array], State]:
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


def _scan_fn(benv: BatchedEnv, mode: str, steps: int) -> Callable[[State, jax.Array], State]:
    env, n = benv.env, benv.num_envs
    one: Callable[[State, jax.Array], State]
    if mode == "full":

        def one_full(state: State, key: jax.Array) -> State:
            return benv.step(state, random_actions(env, key, (n,)))

        one = one_full

    elif mode == "functional":
        vstep = jax.vmap(env.step, in_axes=(0, 0, None))

        def one_functional(state: State, key: jax.Array) -> State:
            return vstep(state, random_actions(env, key, (n,)), env.default_params)

        one = one_functional

    elif mode == "physics":
        one = _physics_step(env)

    else:
        raise ValueError(f"unknown mode {mode!r}; choose from {', '.join(MODES)}")

    def run(state: State, key: jax.Array) -> State:
        def body(s: State, k: jax.Array) -> tuple[State, None]:
            return one(s, k), None

        keys = jax.random.split(key, steps)
        state, _ = jax.lax.scan(body, state, keys, unroll=benv.scan_unroll)
        return state

    return run


def prepare_ours(
    env_id: str,
    num_envs: int,
    mode: str = "full",
    steps: int = 100,
    devices: int | None = None,
    physics: str | None = None,
) -> Runner:
    """Compile and warm up ``steps`` batched steps of ``env_id`` at ``num_envs`` envs.

    ``devices`` > 1 runs the full step through :mod:`jaxenvs.sharding` with the batch
    split over that many devices (each timed call then also includes one reset).
    ``physics`` picks the engine (default: the task's ``auto`` choice); the result's
    ``physics`` field names the one used.
    """
    overrides: dict[str, Any] = {} if physics is None else {"physics": physics}
    benv = jaxenvs.make(env_id, num_envs=num_envs, **overrides)
    assert isinstance(benv, BatchedEnv)
    if devices is not None and devices > 1:
        runner = _prepare_sharded(env_id, benv, mode, steps, devices)
    else:
        runner = prepare_batched(benv, env_id, mode, steps)
    return runner


def prepare_batched(
    benv: BatchedEnv, task: str, mode: str = "full", steps: int = 100, variant: str | None = None
) -> Runner:
    """:func:`prepare_ours` for an env already built (e.g. with config overrides), on one
    device; the runner is filed under ``task`` with ``variant`` (default: ``mode``)."""
    num_envs = benv.num_envs
    run = jax.jit(_scan_fn(benv, mode, steps), donate_argnums=0)
    keys = iter(jax.random.split(jax.random.key(0), 1_000_000))

    t0 = time.perf_counter()
    state = jax.jit(benv.reset)(next(keys))
    jax.block_until_ready(state)
    reset_s = time.perf_counter() - t0
    t0 = time.perf_counter()
    lowered = run.lower(state, next(keys))
    trace_s = time.perf_counter() - t0
    t0 = time.perf_counter()
    compiled = lowered.compile()
    compile_s = time.perf_counter() - t0
    t0 = time.perf_counter()
    state = jax.block_until_ready(compiled(state, next(keys)))
    run_s = time.perf_counter() - t0
    mem = compiled.memory_analysis()
    info: dict[str, Any] = {
        "steps_per_call": steps,
        "substeps": benv.env.sim.substeps,
        "first_call_s": trace_s + compile_s + run_s,
        "first_reset_s": reset_s,
        "trace_s": trace_s,
        "compile_s": compile_s,
        "xla_memory_mib": None
        if mem is None
        else (mem.argument_size_in_bytes + mem.output_size_in_bytes + mem.temp_size_in_bytes)
        / 2**20,
        "devices": benv.devices,
        **_engine_info(benv.env),
    }
    holder = [state]

    def unit() -> int:
        holder[0] = jax.block_until_ready(compiled(holder[0], next(keys)))
        return num_envs * steps

    return Runner("jaxenvs", task, variant or mode, num_envs, unit, info)


def _prepare_sharded(env_id: str, benv: BatchedEnv, mode: str, steps: int, devices: int) -> Runner:
    from jaxenvs import sharding

    if mode != "full":
        raise ValueError("--devices > 1 measures the full (auto-resetting) step only")
    mesh = sharding.make_mesh(devices)
    rollout = sharding.make_sharded_rollout(benv, mesh, steps)
    keys = iter(jax.random.split(jax.random.key(0), 1_000_000))
    t0 = time.perf_counter()
    jax.block_until_ready(rollout(next(keys)))
    info = {
        "steps_per_call": steps,
        "substeps": benv.env.sim.substeps,
        "first_call_s": time.perf_counter() - t0,
        "devices": devices,
        "note": "each call includes one reset",
        **_engine_info(benv.env),
    }

    def unit() -> int:
        jax.block_until_ready(rollout(next(keys)))
        return benv.num_envs * steps

    return Runner("jaxenvs", env_id, mode, benv.num_envs, unit, info)


def _engine_info(env: Env) -> dict[str, Any]:
    info: dict[str, Any] = {"physics": env.physics}
    engine = getattr(env.sim, "engine", None)
    if engine is not None:
        info["threads"] = engine.threads
    return info


def is_ours(result: dict[str, Any]) -> bool:
    """True for our own results (either engine), False for a peer's."""
    return bool(result["name"] == "jaxenvs")


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
        t0 = time.perf_counter()
        r.unit()
        dt = max(time.perf_counter() - t0, 1e-6)
        units.append(max(1, min(10_000, round(target_s / dt))))
    rates: list[list[float]] = [[] for _ in runners]
    for i in range(repeats):
        for j, r in enumerate(runners):
            t0 = time.perf_counter()
            done = sum(r.unit() for _ in range(units[j]))
            rates[j].append(done / (time.perf_counter() - t0))
        if log:
            log(f"round {i + 1}/{repeats} done")
    out = []
    for r, rs, u in zip(runners, rates, units, strict=True):
        sps = statistics.median(rs)
        res = {
            "name": r.name,
            "task": r.task,
            "variant": r.variant,
            "num_envs": r.num_envs,
            "env_steps_per_s": sps,
            "min_env_steps_per_s": min(rs),
            "max_env_steps_per_s": max(rs),
            "units_per_call": u,
            **r.info,
        }
        if "substeps" in r.info:
            res["physics_steps_per_s"] = sps * r.info["substeps"]
        out.append(res)
    return out


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


# --------------------------------------------------------------------------- peers
def _why(err: Exception) -> str:
    if isinstance(err, ImportError):
        return f"not installed (pip install 'jaxenvs[bench]'): {err}"
    return f"{type(err).__name__}: {err}"


def _rng() -> np.random.Generator:
    return np.random.default_rng(0)


def _gymnasium_single(task: str, gym_id: str) -> Runner | Skipped:
    try:
        import gymnasium

        env = gymnasium.make(gym_id)
    except Exception as err:  # missing mujoco bindings, unknown id, ...
        return Skipped("gymnasium", task, gym_id, _why(err))
    env.action_space.seed(0)
    env.reset(seed=0)
    actions = [env.action_space.sample() for _ in range(256)]
    chunk = 200

    def unit() -> int:
        for i in range(chunk):
            _, _, term, trunc, _ = env.step(actions[i % 256])
            if term or trunc:
                env.reset()
        return chunk

    return Runner("gymnasium", task, gym_id, 1, unit, {"threads": 1})


def _gymnasium_sync(task: str, gym_id: str, num_envs: int) -> Runner | Skipped:
    try:
        import gymnasium

        venv = gymnasium.vector.SyncVectorEnv([lambda: gymnasium.make(gym_id)] * num_envs)
    except Exception as err:
        return Skipped("gymnasium SyncVectorEnv", task, gym_id, _why(err))
    venv.action_space.seed(0)
    venv.reset(seed=0)
    actions = [venv.action_space.sample() for _ in range(64)]
    chunk = 20

    def unit() -> int:
        for i in range(chunk):
            venv.step(actions[i % 64])
        return chunk * num_envs

    return Runner("gymnasium SyncVectorEnv", task, gym_id, num_envs, unit, {"threads": 1})


def _envpool(task: str, pool_id: str, num_envs: int, threads: int) -> Runner | Skipped:
    try:
        import envpool

        env = envpool.make(
            pool_id,
            env_type="gymnasium",
            num_envs=num_envs,
            batch_size=num_envs,
            num_threads=threads,
            seed=0,
        )
    except Exception as err:
        return Skipped("envpool", task, pool_id, _why(err))
    env.reset()
    space = env.action_space
    rng = _rng()
    if hasattr(space, "n"):
        actions = rng.integers(0, space.n, (16, num_envs))
    else:
        lo, hi = space.low, space.high
        actions = rng.uniform(lo, hi, (16, num_envs, *space.shape)).astype(space.dtype)

    def unit() -> int:
        for a in actions:
            env.step(a)
        return len(actions) * num_envs

    return Runner("envpool", task, pool_id, num_envs, unit, {"threads": threads})


def _gymnax(task: str, num_envs: int, steps: int) -> Runner | Skipped:
    try:
        import gymnax

        env, params = gymnax.make("CartPole-v1")
    except Exception as err:
        return Skipped("gymnax", task, "CartPole-v1", _why(err))
    reset = jax.vmap(env.reset, in_axes=(0, None))
    vstep = jax.vmap(env.step, in_axes=(0, 0, 0, None))

    def run(carry: Any, key: jax.Array) -> Any:
        def body(c: Any, k: jax.Array) -> tuple[Any, None]:
            state, _ = c
            ks, ka = jax.random.split(k)
            act = jax.random.randint(ka, (num_envs,), 0, 2)
            out = vstep(jax.random.split(ks, num_envs), state, act, params)
            return (out[1], out[0]), None

        carry, _ = jax.lax.scan(body, carry, jax.random.split(key, steps))
        return carry

    fn = jax.jit(run, donate_argnums=0)
    obs, state = reset(jax.random.split(jax.random.key(0), num_envs), params)
    keys = iter(jax.random.split(jax.random.key(1), 1_000_000))
    holder = [jax.block_until_ready(fn((state, obs), next(keys)))]

    def unit() -> int:
        holder[0] = jax.block_until_ready(fn(holder[0], next(keys)))
        return num_envs * steps

    return Runner("gymnax", task, "CartPole-v1", num_envs, unit, {"note": "closed form, no MuJoCo"})


def _mujoco_rollout(task: str, env: Env, num_envs: int, threads: int) -> Runner | Skipped:
    try:
        import mujoco
        from mujoco import rollout
    except Exception as err:
        return Skipped("mujoco.rollout", task, "our MJCF", _why(err))
    # the model our MJX step runs (the MJCF without cameras, lights and non-colliding
    # geoms: jaxenvs.sim.physics_model), so both sides do the same physics work
    model = getattr(env.sim, "physics_mj_model", env.sim.mj_model)
    substeps = env.sim.substeps
    data = mujoco.MjData(model)
    if model.nkey > 0:
        mujoco.mj_resetDataKeyframe(model, data, 0)
    mujoco.mj_forward(model, data)
    spec = mujoco.mjtState.mjSTATE_FULLPHYSICS
    x0 = np.empty(mujoco.mj_stateSize(model, spec))
    mujoco.mj_getState(model, data, x0, spec)
    env_steps = max(1, 200 // substeps)
    nstep = env_steps * substeps
    rng = _rng()
    lo, hi = model.actuator_ctrlrange[:, 0], model.actuator_ctrlrange[:, 1]
    ctrl = rng.uniform(lo, hi, (num_envs, env_steps, model.nu))
    ctrl = np.repeat(ctrl, substeps, axis=1)
    x0s = np.tile(x0, (num_envs, 1))
    datas = [mujoco.MjData(model) for _ in range(threads)]
    out = np.empty((num_envs, nstep, x0.size))
    sens = np.empty((num_envs, nstep, model.nsensordata))

    def unit() -> int:
        rollout.rollout(model, datas, x0s, ctrl, nstep=nstep, state=out, sensordata=sens)
        return num_envs * env_steps

    info = {"threads": threads, "substeps": substeps, "timestep": model.opt.timestep}
    return Runner("mujoco.rollout", task, "our MJCF", num_envs, unit, info)


def peer_runners(
    task: str,
    num_envs: int = 256,
    gymnax_envs: int = 16384,
    threads: int | None = None,
    sync_envs: int = 16,
) -> list[Runner | Skipped]:
    """Every peer of ``task``, prepared; missing ones as :class:`Skipped`.

    All tasks get MuJoCo's C rollout on our own MJCF at our substeps (``threads`` threads,
    default all cores); tasks with a Gymnasium/EnvPool counterpart (:data:`PEER_IDS`) get
    those too (one env and a ``sync_envs`` SyncVectorEnv; EnvPool at ``num_envs`` envs);
    ``CartPole-v0`` also gets gymnax's closed-form CartPole at ``gymnax_envs`` envs.
    """
    threads = threads or os.cpu_count() or 1
    env = jaxenvs.make(task)
    assert isinstance(env, Env)
    makers: list[tuple[str, str, Callable[[], Runner | Skipped]]] = []
    if task in PEER_IDS:
        gym_id, pool_id = PEER_IDS[task]
        makers += [
            ("gymnasium", gym_id, lambda: _gymnasium_single(task, gym_id)),
            ("gymnasium SyncVectorEnv", gym_id, lambda: _gymnasium_sync(task, gym_id, sync_envs)),
            ("envpool", pool_id, lambda: _envpool(task, pool_id, num_envs, threads)),
        ]
    makers.append(
        ("mujoco.rollout", "our MJCF", lambda: _mujoco_rollout(task, env, num_envs, threads))
    )
    if task == "CartPole-v0":
        makers.append(("gymnax", "CartPole-v1", lambda: _gymnax(task, gymnax_envs, 100)))
    out: list[Runner | Skipped] = []
    for name, variant, make in makers:
        try:
            out.append(make())
        except Exception as err:  # a peer that breaks while warming up is reported, not fatal
            out.append(Skipped(name, task, variant, _why(err)))
    return out


# --------------------------------------------------------------------------- reports
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


def ratios(results: Sequence[dict[str, Any]]) -> list[dict[str, Any]]:
    """Ours (best batch, full step, each engine measured) / each peer of the same task."""
    rows = []
    for peer in results:
        if is_ours(peer) or peer.get("skipped"):
            continue
        engines = {r.get("physics", "mjx") for r in results if is_ours(r)}
        for physics in sorted(engines):
            best = best_of(results, peer["task"], physics=physics)
            if best is None:
                continue
            rows.append(
                {
                    "task": peer["task"],
                    "physics": physics,
                    "our_envs": best["num_envs"],
                    "ours": best["env_steps_per_s"],
                    "peer": f"{peer['name']} {peer['variant']} x{peer['num_envs']}",
                    "peer_steps_per_s": peer["env_steps_per_s"],
                    "ratio": best["env_steps_per_s"] / peer["env_steps_per_s"],
                }
            )
    return rows


def format_table(rows: Sequence[Sequence[Any]]) -> str:
    """Left-aligned text columns."""
    cells = [[str(c) for c in row] for row in rows]
    widths = [max(len(r[i]) for r in cells) for i in range(len(cells[0]))]
    return "\n".join("  ".join(c.ljust(w) for c, w in zip(r, widths, strict=True)) for r in cells)


def plot(results: Sequence[dict[str, Any]], path: str) -> None:
    """Log-log env steps/s vs batch, one panel per task, peers as horizontal lines."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    tasks = list(dict.fromkeys(r["task"] for r in results if not r.get("skipped")))
    fig, axes = plt.subplots(1, len(tasks), figsize=(5 * len(tasks), 4), squeeze=False)
    for ax, task in zip(axes[0], tasks, strict=True):
        rows = [r for r in results if r["task"] == task and not r.get("skipped")]
        for mode in MODES:
            for physics in ("mjx", "c"):
                pts = sorted(
                    (r["num_envs"], r["env_steps_per_s"])
                    for r in rows
                    if is_ours(r) and r["variant"] == mode and r.get("physics", "mjx") == physics
                )
                if pts:
                    label = f"jaxenvs {mode} ({physics})"
                    ax.plot(*zip(*pts, strict=True), marker="o", label=label)
        for i, r in enumerate(r for r in rows if not is_ours(r)):
            ax.axhline(
                r["env_steps_per_s"],
                ls="--",
                color=f"C{(i + 3) % 10}",
                label=f"{r['name']} {r['variant']} x{r['num_envs']}",
            )
        ax.set_xscale("log", base=2)
        ax.set_yscale("log")
        ax.set_xlabel("envs")
        ax.set_ylabel("env steps/s")
        ax.set_title(task)
        ax.legend(fontsize=6)
    fig.tight_layout()
    with files.atomic_path(path) as tmp:
        fig.savefig(tmp, dpi=120)
    plt.close(fig)
