"""physics='auto' on a CPU: both engines over a batch sweep with auto's pick, and the C
engine's costs (memory, first call)."""

from __future__ import annotations

import statistics
from typing import Any

from .common import Cells, Rec, Table, by_engine, one, rate, rows, secs


def engines_sweep(recs: list[Rec]) -> Cells:
    """Both engines at each batch size, what physics='auto' picks there (today's rule: the
    task's class attributes read from jaxenvs, with the record machine's CPU device count),
    and auto over the faster engine."""
    return _sweep(recs, auto=True)


def engines_sweep_before(recs: list[Rec]) -> Cells:
    """Both engines at each batch size, the faster one and C over MJX: a sweep taken
    before the rule's evidence changed (the rule of its day is in the prose beside it)."""
    return _sweep(recs, auto=False)


def _sweep(recs: list[Rec], auto: bool) -> Cells:
    from jaxenvs import registry
    from jaxenvs.physics import resolve_engine

    picks = ["auto picks", "auto / faster"] if auto else ["faster", "C / MJX"]
    cells = [["task", "envs", "MJX", "C", *picks, "MJX first call", "C first call"]]
    for rec, task, mjx, c in by_engine(recs):
        factory = registry.spec(task).factory
        devices = rec.get("extra", {}).get("machine", {}).get("device_count", 1)
        by_c = {r["num_envs"]: r for r in c}
        for m in (m for m in mjx if m["num_envs"] in by_c):
            n = m["num_envs"]
            cr = by_c[n]
            m_rate, c_rate = m["env_steps_per_s"], cr["env_steps_per_s"]
            if auto:
                pick = resolve_engine(factory, "auto", n, backend="cpu", cpu_devices=devices)
                got = m_rate if pick == "mjx" else c_rate
                fast = max(m_rate, c_rate)
                ratio = f"{got / fast:.2f}" + ("" if got / fast >= 0.9 else " (**below 0.9**)")
            else:
                pick, ratio = ("mjx" if m_rate > c_rate else "c"), f"{c_rate / m_rate:.2f}"
            cells.append(
                [
                    task,
                    f"{n:,}",
                    rate(m_rate),
                    rate(c_rate),
                    pick,
                    ratio,
                    secs(m["first_call_s"]),
                    secs(cr["first_call_s"]),
                ]
            )
        for r in rows(rec, task=task):
            if r.get("name") in ("mujoco.rollout", "envpool") and not r.get("skipped"):
                who = f"{r['name']} {r.get('variant', '')}".strip()
                cells.append(
                    [task, f"{r['num_envs']:,}", "", "", who, rate(r["env_steps_per_s"]), "", ""]
                )
    return cells


def device_count(recs: list[Rec]) -> Cells:
    """Each engine, task and batch under each host-device count of one record, and the
    ratio of the larger count's throughput over the smaller's."""
    (rec,) = recs
    counts = sorted({r["host_devices"] for r in rows(rec)})
    low, high = counts[0], counts[-1]
    cells = [["task", "engine", "envs", *[f"{n} host devices" for n in counts], f"{high} / {low}"]]
    got: dict[tuple[str, str, int, int], Any] = {}
    for r in rows(rec):
        got[(r["task"], r["physics"], r["num_envs"], r["host_devices"])] = r
    for task, physics, n in sorted({k[:3] for k in got}):
        runs = [got.get((task, physics, n, d)) for d in counts]
        if any(r is None for r in runs):
            continue
        figures = [f"{rate(r['env_steps_per_s'])} ({r['devices']})" for r in runs]
        ratio = runs[-1]["env_steps_per_s"] / runs[0]["env_steps_per_s"]
        cells.append([task, physics, f"{n:,}", *figures, f"{ratio:.2f}"])
    return cells


def reset_ab(recs: list[Rec]) -> Cells:
    """The compact auto-reset against resetting the whole batch: each task, engine and
    batch of each record, and ``mujoco.rollout`` beside them."""
    cells = [["task", "engine", "envs", "compact", "whole batch", "compact / whole", "devices"]]
    for rec in recs:
        got: dict[tuple[str, str, int], dict[str, Any]] = {}
        for r in rows(rec):
            if r["name"] == "mujoco.rollout":
                cells.append(
                    [r["task"], "mujoco.rollout", f"{r['num_envs']:,}", rate(r["env_steps_per_s"])]
                    + ["", "", ""]
                )
                continue
            kind, _, engine = r["variant"].partition("_")
            got[(r["task"], engine or "c", r["num_envs"], kind)] = r
        for head, a, _ in _pairs(got, "compact", "whole"):
            cells.append([*head, str(a.get("devices"))])
    return cells


def _pairs(
    got: dict[tuple[str, str, int, str], dict[str, Any]], first: str, second: str
) -> list[tuple[list[str], dict[str, Any], dict[str, Any]]]:
    """For each (task, engine, envs) of ``got`` (keyed by those and a variant) measured as
    both ``first`` and ``second``: the cells task, engine, envs, both throughputs and their
    ratio, and the two rows."""
    out = []
    for task, engine, n in sorted({k[:3] for k in got}):
        a, b = got.get((task, engine, n, first)), got.get((task, engine, n, second))
        if a is None or b is None:
            continue
        fa, fb = a["env_steps_per_s"], b["env_steps_per_s"]
        out.append(([task, engine, f"{n:,}", rate(fa), rate(fb), f"{fa / fb:.2f}"], a, b))
    return out


def c_costs(recs: list[Rec]) -> Cells:
    (rec,) = recs
    cells = [["measure", "what", "figure"]]
    for r in rows(rec, measure="memory"):
        params = "randomised" if r["randomize"] else "default"
        cache = r.get("compile_cache", "cold")
        what = f"{r['envs']:,} walkers, {params} params, {cache} compile cache"
        cells.append(
            ["peak RSS above `import jaxenvs`", what, f"{r['peak_mib_above_import']:.0f} MiB"]
        )
    for r in rows(rec, measure="first_call"):
        cells.append(["first reset + step, 16 envs", r["task"], secs(r["first_call_s"])])
    return cells


def c_memory(recs: list[Rec]) -> Cells:
    """Peak RSS by stage (medians of the runs) of each checkout and compiler, cold and
    warm (files before the compiler column were all compiled by plain ``jax.jit``)."""
    (rec,) = recs
    stages = ("make", "reset_compiled", "reset_ran", "step_compiled", "steps")
    head = ["commit", "compiled by", "compile cache", "runs", "make", "reset compiled"]
    cells = [[*head, "reset ran", "step compiled", "20 steps (peak)", "peaks of the runs"]]
    for r in rows(rec, measure="memory_stages"):
        peaks = ", ".join(f"{run['steps']:.0f}" for run in r["runs"])
        figures = [f"{r[s]:.0f}" for s in stages]
        figures[-1] = f"**{figures[-1]}**"
        jit = f"`{r.get('jit', 'jax.jit')}`"
        cells.append(
            [r["tree_commit"], jit, r["compile_cache"], str(len(r["runs"])), *figures, peaks]
        )
    return cells


def emitters_ab(recs: list[Rec]) -> Cells:
    """XLA's loop emitters (jaxenvs' options) against its fusion emitters: throughput and
    compile time of each task, engine and batch, one record each."""
    cells = [["task", "engine", "envs", "loop", "fusion", "loop / fusion"]]
    cells[0] += ["compile, loop", "compile, fusion"]
    for rec in recs:
        got = {(r["task"], r["physics"], r["num_envs"], r["variant"]): r for r in rows(rec)}
        for head, a, b in _pairs(got, "loop", "fusion"):
            cells.append([*head, secs(a["compile_s"]), secs(b["compile_s"])])
    return cells


def _by_build(
    rec: Rec, name: str = "jaxenvs"
) -> dict[tuple[str, int], dict[str, dict[int, float]]]:
    """``name``'s env steps/s of an A/B record by (task, envs), build and round."""
    got: dict[tuple[str, int], dict[str, dict[int, float]]] = {}
    for r in rows(rec):
        if r.get("name", "jaxenvs") == name:
            per = got.setdefault((r["task"], r["num_envs"]), {}).setdefault(r["build"], {})
            per[r["round"]] = r["env_steps_per_s"]
    return got


def _ab_line(cores: str, task: str, n: int, builds: dict[str, dict[int, float]]) -> list[str]:
    """One line of an A/B table: each build's median, head / base and it per round."""
    base, head = builds["base"], builds["head"]
    mb, mh = statistics.median(base.values()), statistics.median(head.values())
    rounds = ", ".join(f"{head[k] / base[k]:.2f}" for k in sorted(base) if k in head)
    return [cores, task, f"{n:,}", rate(mb), rate(mh), f"{mh / mb:.2f}", rounds]


AB_HEADER = ["cores", "task", "envs", "base", "head", "head / base", "per round"]


def native_ab(recs: list[Rec]) -> Cells:
    """Two builds of the native engine (``benchmarks/native_ab.sh``), per task and batch:
    each build's median over its rounds, and head / base per round (alternating
    processes, so a round's pair ran side by side)."""
    cells = [list(AB_HEADER)]
    for rec in recs:
        cores = str(rec["machine"]["cores"])
        for (task, n), builds in sorted(_by_build(rec).items()):
            cells.append(_ab_line(cores, task, n, builds))
    return cells


def per_device_ab(recs: list[Rec]) -> Cells:
    """:func:`native_ab`'s table of two builds, with each head process's figure over the
    one ``mujoco.rollout`` row of its task timed in the same round by the head build."""
    (rec,) = recs
    cores = str(rec["machine"]["cores"])
    cells = [[*AB_HEADER, "head / rollout, per round"]]
    for (task, n), builds in sorted(_by_build(rec).items()):
        head = builds["head"]
        roll = {
            k: one(rec, task=task, build="head", round=k, name="mujoco.rollout")
            for k in sorted(head)
        }
        per_round = ", ".join(f"{head[k] / roll[k]['env_steps_per_s']:.2f}" for k in roll)
        cells.append([*_ab_line(cores, task, n, builds), per_round])
    return cells


def big_batch(recs: list[Rec]) -> Cells:
    """C per process at each batch beside the one ``mujoco.rollout`` row of the same
    process, and C over rollout."""
    (rec,) = recs
    cells = [["process", "C envs", "C", "rollout envs", "rollout", "C / rollout"]]
    for setup in sorted({r["setup"] for r in rows(rec)}):
        for k in sorted({r["round"] for r in rows(rec) if r["setup"] == setup}):
            mine = [r for r in rows(rec) if (r["setup"], r["round"]) == (setup, k)]
            roll = one(rec, setup=setup, round=k, name="mujoco.rollout")
            for r in (r for r in mine if r.get("name", "jaxenvs") == "jaxenvs"):
                cells.append(
                    [
                        f"{setup}, {k}",
                        f"{r['num_envs']:,}",
                        rate(r["env_steps_per_s"]),
                        f"{roll['num_envs']:,}",
                        rate(roll["env_steps_per_s"]),
                        f"{r['env_steps_per_s'] / roll['env_steps_per_s']:.2f}",
                    ]
                )
    return cells


def shard_threads(recs: list[Rec]) -> Cells:
    """C per setup (host devices; each device's call with its share of the threads or all
    of them), task and batch: the median over rounds, and over the default setup."""
    (rec,) = recs
    got: dict[tuple[str, int], dict[str, list[float]]] = {}
    for r in rows(rec):
        per = got.setdefault((r["task"], r["num_envs"]), {})
        per.setdefault(r["setup"], []).append(r["env_steps_per_s"])
    setups = ["default", "shardall", "dev16", "dev16all"]
    cells = [["task", "envs", *setups, *(f"{s} / default" for s in setups[1:])]]
    for (task, n), by in sorted(got.items()):
        med = [statistics.median(by[s]) for s in setups]
        cells.append([task, f"{n:,}", *map(rate, med), *(f"{m / med[0]:.2f}" for m in med[1:])])
    return cells


def reset_sync(recs: list[Rec]) -> Cells:
    """C at 16,384 envs on 16 cores as one program over 8 devices, against 8 processes of
    2,048 envs on 2 cores each (their sum) and against the same program without the
    auto-reset's cross-device max (medians over rounds), beside ``mujoco.rollout``."""
    (rec,) = recs
    cells = [["task", "one program", "8 processes", "no cross-device max", "mujoco.rollout"]]
    cells[0] += ["8 processes / one", "no max / default"]

    def rates(task: str, setup: str, name: str = "jaxenvs") -> list[float]:
        return [
            r["env_steps_per_s"]
            for r in rows(rec, task=task)
            if r["setup"] == setup and r["name"] == name
        ]

    for task in sorted({r["task"] for r in rows(rec)}):
        one = rates(task, "one process, 8 devices")[0]
        procs = sum(rates(task, "8 processes x 2 cores"))
        default = statistics.median(rates(task, "default"))
        no_max = statistics.median(rates(task, "one chunk, no max"))
        rollout = rates(task, "one process, 8 devices", "mujoco.rollout")[0]
        cells.append(
            [task, rate(one), rate(procs), rate(no_max), rate(rollout)]
            + [f"{procs / one:.2f}", f"{no_max / default:.2f}"]
        )
    return cells


def _sweep_files(machine: str) -> tuple[str, ...]:
    return tuple(
        f"engines_sweep_{machine}_{t}" for t in ("cartpolev0", "reacherv0", "hexapodwalkv0")
    )


TABLES = {
    "native-ab": Table(("native_ab_cpu16", "native_ab_cpu2"), native_ab),
    "reset-every-step-ab": Table(("reset_every_step_ab_cpu16",), native_ab),
    "engines-sweep-cpu16-every": Table(_sweep_files("cpu16every")[:2], engines_sweep),
    "step-per-device-ab": Table(("step_per_device_ab_cpu16",), per_device_ab),
    "engines-sweep-cpu16-shard": Table(_sweep_files("cpu16shard"), engines_sweep),
    "cartpole-big-batch-cpu16": Table(("cartpole_big_batch_cpu16",), big_batch),
    "engines-sweep-cpu16-pool": Table(_sweep_files("cpu16pool"), engines_sweep),
    "engines-sweep-cpu2-pool": Table(_sweep_files("cpu2pool")[:2], engines_sweep),
    "engines-cpu16-shard-threads": Table(("engines_cpu16_shard_threads",), shard_threads),
    "engines-cpu16-reset-sync": Table(("engines_cpu16_reset_sync",), reset_sync),
    "engines-sweep-cpu16-chunks": Table(_sweep_files("cpu16chunks"), engines_sweep_before),
    "engines-sweep-cpu16-compact": Table(_sweep_files("cpu16compact"), engines_sweep_before),
    "engines-cpu16-device-count-compact": Table(
        ("engines_cpu16_device_count_compact",), device_count
    ),
    "auto-reset-ab": Table(("auto_reset_ab_cpu16", "auto_reset_ab_cpu2"), reset_ab),
    "engines-sweep-cpu16-fields": Table(_sweep_files("cpu16fields"), engines_sweep_before),
    "engines-sweep-cpu2-emitters": Table(_sweep_files("cpu2emitters")[:2], engines_sweep_before),
    "engines-sweep-cpu2-fields": Table(_sweep_files("cpu2fields"), engines_sweep_before),
    "engines-cpu16-device-count": Table(("engines_cpu16_device_count",), device_count),
    "engines-sweep-cpu16": Table(_sweep_files("cpu16"), engines_sweep_before),
    "engines-sweep-cpu16-split": Table(_sweep_files("cpu16split"), engines_sweep_before),
    "engines-sweep-cpu16-default": Table(_sweep_files("cpu16default"), engines_sweep_before),
    "engines-sweep-cpu2": Table(_sweep_files("cpu2"), engines_sweep_before),
    "c-costs-cpu2": Table(("c_engine_costs_cpu2",), c_costs),
    "c-memory-cpu2": Table(("c_memory_cpu2",), c_memory),
    "c-memory-cpu2-emitters": Table(("c_memory_cpu2_emitters",), c_memory),
    "c-memory-cpu2-pool": Table(("c_memory_cpu2_pool",), c_memory),
    "c-memory-cpu2-house": Table(("c_memory_cpu2_house",), c_memory),
    "c-memory-cpu2-elliptic": Table(("c_memory_cpu2_elliptic",), c_memory),
    "emitters-ab-cpu2": Table(("compiler_options_ab_cpu2",), emitters_ab),
    "auto-reset-ab-chunks": Table(
        ("auto_reset_ab_cpu16chunks", "auto_reset_ab_cpu2chunks"), reset_ab
    ),
}
