"""Engines: both engines beside the peers on 2 cores and on 16 cores, and their targets."""

from __future__ import annotations

from .common import (
    HFIELD_COLLIDERS,
    Cells,
    Rec,
    Row,
    Table,
    best,
    best_sps,
    by_engine,
    each_row,
    first_calls,
    maybe,
    met,
    one,
    one_sps,
    ours,
    rate,
    ratio,
    rows,
    secs,
    sps,
    target,
)


def engines_cpu2(recs: list[Rec]) -> Cells:
    cells = [
        [
            "task",
            "envs",
            "MJX env steps/s (first call)",
            "C env steps/s (first call)",
            "`mujoco.rollout` x256, 2 threads",
            "EnvPool x256",
        ]
    ]
    for rec, task, mjx, c in by_engine(recs):
        roll = maybe(rec, task=task, name="mujoco.rollout")
        pool = maybe(rec, task=task, name="envpool")
        cells.append(
            [
                task,
                " / ".join(str(r["num_envs"]) for r in mjx),
                f"{sps(mjx)} ({first_calls(mjx)})",
                f"{sps(c)} ({first_calls(c)})",
                rate(roll["env_steps_per_s"]) if roll else "",
                f"{pool['variant']} {rate(pool['env_steps_per_s'])}" if pool else "",
            ]
        )
    return cells


def engines_cpu2_targets(recs: list[Rec]) -> Cells:
    _, walker, _ = recs
    c_walk = best_sps(ours(walker, "HexapodWalk-v0", "c"))
    firsts = [
        r["first_call_s"]
        for rec in recs
        for r in rows(rec, name="jaxenvs", physics="c")
        if not r.get("skipped")
    ]
    return [
        ["target", "measured", "met?"],
        target("walker under C >= 2x EnvPool Ant-v4", c_walk, one_sps(walker, name="envpool"), 2),
        target(
            "walker under C >= 0.8x raw `mujoco.rollout` on our MJCF",
            c_walk,
            one_sps(walker, name="mujoco.rollout"),
            0.8,
        ),
        [
            "first call <= 3 s for every task under C (bench's first call includes "
            "the first 50-100 steps)",
            f"{min(firsts):.1f}-{max(firsts):.1f} s",
            met(max(firsts) <= 3.0),
        ],
    ]


def _compile(found: list[Row]) -> str:
    t = [r["trace_s"] + r["compile_s"] for r in found]
    return secs(min(t)) if max(t) - min(t) < 0.05 else f"{min(t):.1f}-{max(t):.1f} s"


def engines_cpu16(recs: list[Rec]) -> Cells:
    """The 16-core sweep: CartPole and the reacher, the walker, then the walker's MJX on
    one XLA device."""
    cr, walker, one_dev = recs
    cells = cpu16_rows([cr, walker])
    r = one(one_dev, name="jaxenvs")
    cells.append(
        [
            f"{r['task']}, MJX on one XLA device",
            f"{r['num_envs']:,}",
            f"{rate(r['env_steps_per_s'])} ({_compile([r])})",
            *[""] * 4,
        ]
    )
    return cells


def cpu16_rows(recs: list[Rec]) -> Cells:
    """Each task of ``recs`` under MJX and C beside `mujoco.rollout`, 16 cores."""
    cells = [
        [
            "task",
            "envs",
            "MJX, 8 devices (trace+compile)",
            "C, 16 threads (trace+compile)",
            "`mujoco.rollout` x256, 16 threads",
            "MJX / rollout",
            "C / rollout",
        ]
    ]
    for rec, task, mjx, c in by_engine(tuple(recs)):
        roll = one_sps(rec, task=task, name="mujoco.rollout")
        cells.append(
            [
                task,
                " / ".join(f"{r['num_envs']:,}" for r in mjx),
                f"{sps(mjx)} ({_compile(mjx)})",
                f"{sps(c)} ({_compile(c)})",
                rate(roll),
                ratio(best_sps(mjx), roll),
                ratio(best_sps(c), roll),
            ]
        )
    return cells


def engines_cpu16_targets(recs: list[Rec]) -> Cells:
    cr, walker, one_dev = recs
    cells = [
        ["target", "measured", "met?"],
        target(
            "walker under C >= 0.7x `mujoco.rollout`, 16 threads",
            best_sps(ours(walker, "HexapodWalk-v0", "c")),
            one_sps(walker, name="mujoco.rollout"),
            0.7,
        ),
    ]
    for task, bar in (("CartPole-v0", 1.5), ("Reacher-v0", 1.2)):
        cells.append(
            target(
                f"{task} default settings >= {bar}x `mujoco.rollout`, 16 threads",
                best_sps(ours(cr, task, "mjx")),
                one_sps(cr, task=task, name="mujoco.rollout"),
                bar,
            )
        )
    many = best(ours(walker, "HexapodWalk-v0", "mjx"))
    single = one(one_dev, name="jaxenvs")
    cells.append(
        [
            "HexapodWalk-v0 under MJX >= 7x its one-device figure",
            f"{rate(many['env_steps_per_s'])} (8 devices, {many['num_envs']:,} envs) / "
            f"{rate(single['env_steps_per_s'])} (1 device, {single['num_envs']:,} envs) = "
            f"**{ratio(many['env_steps_per_s'], single['env_steps_per_s'])}**",
            met(many["env_steps_per_s"] >= 7 * single["env_steps_per_s"]),
        ]
    )
    return cells


def terrain_throughput(recs: list[Rec]) -> Cells:
    """The rough joystick's env steps/s over the flat joystick's, per batch, solver and
    (under MuJoCo C) heightfield collider, against the 0.8x target."""
    (rec,) = recs

    def cells(r: Row) -> list[str]:
        flat = r["variant"] == "flat"
        solver = "-" if flat else r.get("solver", "auto (the config's)")
        # a row without the field ran the task's default collider
        collider = (
            "-"
            if flat or r["physics"] != "c"
            else HFIELD_COLLIDERS[r.get("hfield_contact", "surface")]
        )
        return [
            r["task"],
            solver,
            r["physics"],
            collider,
            f"{r['num_envs']:,}",
            rate(r["env_steps_per_s"]),
            f"**{r['x_flat']:.2f}x**",
            secs(r["first_call_s"]),
            "" if flat else met(r["x_flat"] >= 0.8),
        ]

    head = [
        "task",
        "rough solver",
        "engine",
        "C heightfield collider",
        "envs",
        "env steps/s",
        "x flat",
        "first call",
        ">= 0.8x",
    ]
    return each_row(head, rec["rows"], cells)


def terrain_throughput_contacts(
    recs: list[Rec], default: str = "8 (the task's default then)"
) -> Cells:
    """The same per MJX contact budget (``max_contacts``), against the 0.8x target; a
    row without one ran the task's default, named by ``default``."""
    (rec,) = recs

    def cells(r: Row) -> list[str]:
        flat, cap = r["variant"] == "flat", r.get("max_contacts")
        kept = "-" if flat else default if cap is None else str(cap or "all 24")
        return [
            r["task"],
            kept,
            f"{r['num_envs']:,}",
            rate(r["env_steps_per_s"]),
            f"**{r['x_flat']:.2f}x**",
            secs(r["first_call_s"]),
            "" if flat else met(r["x_flat"] >= 0.8),
        ]

    head = ["task", "MJX contacts kept", "envs", "env steps/s", "x flat", "first call", ">= 0.8x"]
    return each_row(head, rec["rows"], cells)


ENGINES_CPU2 = (
    "engines_cpu2_cartpole_reacher",
    "engines_cpu2_walker",
    "engines_cpu2_cartpole_tasks_oneleg",
)
ENGINES_CPU16 = (
    "engines_cpu16_cartpole_reacher",
    "engines_cpu16_walker",
    "engines_cpu16_walker_mjx_one_device",
)

TABLES = {
    "engines-cpu2": Table(ENGINES_CPU2, engines_cpu2),
    "engines-cpu2-targets": Table(ENGINES_CPU2, engines_cpu2_targets),
    "engines-cpu16": Table(ENGINES_CPU16, engines_cpu16),
    "engines-cpu16-targets": Table(ENGINES_CPU16, engines_cpu16_targets),
    "terrain-throughput-cpu2": Table(("terrain_throughput_cpu2",), terrain_throughput),
    "terrain-throughput-h200": Table(("terrain_throughput_h200",), terrain_throughput),
    "terrain-throughput-contacts-h200": Table(
        ("terrain_throughput_h200_max_contacts",), terrain_throughput_contacts
    ),
    "terrain-throughput-margin10-h200": Table(
        ("terrain_throughput_h200_margin10",), terrain_throughput_contacts
    ),
    "terrain-throughput-contacts7-h200": Table(
        ("terrain_throughput_h200_contacts7",), terrain_throughput_contacts
    ),
    "terrain-throughput-contacts6-h200": Table(
        ("terrain_throughput_h200_contacts6",), terrain_throughput_contacts
    ),
    "terrain-throughput-default6-h200": Table(
        ("terrain_throughput_h200_default6",),
        lambda recs: terrain_throughput_contacts(recs, "6 (the task's default)"),
    ),
    "engines-cpu16-per-device": Table(("engines_cpu16_cartpole_reacher_per_device",), cpu16_rows),
}
