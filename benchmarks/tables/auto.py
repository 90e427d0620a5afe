"""physics='auto' on a CPU: both engines over a batch sweep with auto's pick, and the C
engine's costs (memory, first call)."""

from __future__ import annotations

from .common import Cells, Rec, Table, by_engine, rate, rows, secs


def engines_sweep(recs: list[Rec]) -> Cells:
    """Both engines at each batch size, what physics='auto' picks there (the task's class
    attribute ``cpu_mjx_from``, read from jaxenvs), and auto over the faster engine."""
    from jaxenvs import registry
    from jaxenvs.physics import resolve_engine

    cells = [
        [
            "task",
            "envs",
            "MJX",
            "C",
            "auto picks",
            "auto / faster",
            "MJX first call",
            "C first call",
        ]
    ]
    for rec, task, mjx, c in by_engine(recs):
        factory = registry.spec(task).factory
        by_c = {r["num_envs"]: r for r in c}
        for m in (m for m in mjx if m["num_envs"] in by_c):
            n = m["num_envs"]
            cr = by_c[n]
            pick = resolve_engine(factory, "auto", n, backend="cpu")
            got = (m if pick == "mjx" else cr)["env_steps_per_s"]
            fast = max(m["env_steps_per_s"], cr["env_steps_per_s"])
            cells.append(
                [
                    task,
                    f"{n:,}",
                    rate(m["env_steps_per_s"]),
                    rate(cr["env_steps_per_s"]),
                    str(pick),
                    f"{got / fast:.2f}" + ("" if got / fast >= 0.9 else " (**below 0.9**)"),
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
    """Peak RSS by stage (medians of the runs) of each checkout, cold and warm."""
    (rec,) = recs
    stages = ("make", "reset_compiled", "reset_ran", "step_compiled", "steps")
    head = ["commit", "compile cache", "runs", "make", "reset compiled", "reset ran"]
    cells = [[*head, "step compiled", "20 steps (peak)", "peaks of the runs"]]
    for r in rows(rec, measure="memory_stages"):
        peaks = ", ".join(f"{run['steps']:.0f}" for run in r["runs"])
        figures = [f"{r[s]:.0f}" for s in stages]
        figures[-1] = f"**{figures[-1]}**"
        cells.append([r["tree_commit"], r["compile_cache"], str(len(r["runs"])), *figures, peaks])
    return cells


def _sweep_files(machine: str) -> tuple[str, ...]:
    return tuple(
        f"engines_sweep_{machine}_{t}" for t in ("cartpolev0", "reacherv0", "hexapodwalkv0")
    )


TABLES = {
    "engines-sweep-cpu16": Table(_sweep_files("cpu16"), engines_sweep),
    "engines-sweep-cpu16-split": Table(_sweep_files("cpu16split"), engines_sweep),
    "engines-sweep-cpu16-default": Table(_sweep_files("cpu16default"), engines_sweep),
    "engines-sweep-cpu2": Table(_sweep_files("cpu2"), engines_sweep),
    "c-costs-cpu2": Table(("c_engine_costs_cpu2",), c_costs),
    "c-memory-cpu2": Table(("c_memory_cpu2",), c_memory),
}
