"""Throughput: ours beside the peers on 2 cores, and on GPUs: the lean device model, the
three step modes, and the walker's solver variants."""

from __future__ import annotations

from .common import (
    Cells,
    Rec,
    Row,
    Table,
    best_sps,
    each_row,
    first_calls,
    one_sps,
    ours,
    rate,
    ratio,
    rows,
    secs,
    sps,
    tasks,
)


def peers_cpu2(recs: list[Rec]) -> Cells:
    cells = [
        [
            "run",
            "task",
            "ours, 4,096 / 16,384 envs",
            "EnvPool, 256 envs",
            "ratio",
            "`mujoco.rollout`, 256 envs",
            "ratio",
            "first call (worst)",
        ]
    ]
    for rec in recs:
        for task in tasks(rec):
            found = ours(rec, task)
            top = best_sps(found)
            pool = one_sps(rec, task=task, name="envpool")
            roll = one_sps(rec, task=task, name="mujoco.rollout")
            cells.append(
                [
                    f"`{rec['name']}`",
                    task,
                    sps(found),
                    rate(pool),
                    f"**{ratio(top, pool)}**",
                    rate(roll),
                    ratio(top, roll),
                    secs(max(r["first_call_s"] for r in found)),
                ]
            )
    return cells


def gpu_h100(recs: list[Rec]) -> Cells:
    lean, plain = recs
    cells = [["task", "device model", "envs", "env steps/s, round 1 / round 2", "first call"]]
    for task in dict.fromkeys(r["task"] for r in lean["rows"]):
        for is_lean in (False, True):
            for n in sorted({r["num_envs"] for r in rows(lean, task=task)}):
                found = rows(lean, task=task, num_envs=n, lean_model=is_lean)
                found.sort(key=lambda r: r["round"])
                model = "lean" if is_lean else "full"
                cells.append([task, model, f"{n:,}", sps(found), first_calls(found)])
    for r in plain["rows"]:
        cells.append(
            [
                r["task"],
                "lean, plain `mjx.step` (current)",
                f"{r['num_envs']:,}",
                rate(r["env_steps_per_s"]),
                secs(r["first_call_s"]),
            ]
        )
    return cells


def throughput_h200(recs: list[Rec]) -> Cells:
    (rec,) = recs

    def cells(r: Row) -> list[str]:
        return [
            r["task"],
            f"{r['num_envs']:,}",
            rate(r["full"]),
            rate(r["functional"]),
            rate(r["physics"]),
            secs(r["first_call_s_full"]),
            f"{r['xla_program_mib']:,}",
        ]

    head = [
        "task",
        "envs",
        "full",
        "functional",
        "physics (raw `mjx.step`)",
        "first call (full)",
        "XLA program MiB",
    ]
    return each_row(head, rec["rows"], cells)


def walker_solver(recs: list[Rec]) -> Cells:
    (rec,) = recs
    stab = rec["extra"]["stability"]
    base = one_sps(rec, variant="base")

    def cells(r: Row) -> list[str]:
        s = stab[r["variant"]]
        return [
            r["variant"] + (" (shipped)" if r["variant"] == "base" else ""),
            str(r["substeps"]),
            f"{r['num_envs']:,}",
            rate(r["env_steps_per_s"]),
            ratio(r["env_steps_per_s"], base),
            secs(r["first_call_s"]),
            f"{s['stance_height_m']:.3f} m",
            f"{s['stance_max_joint_speed']:.2g} rad/s",
            f"{s['random_diverged_per_1000_steps']:g}",
        ]

    head = [
        "variant",
        "substeps",
        "envs",
        "env steps/s",
        "x shipped",
        "first call",
        "stance height",
        "stance max joint speed",
        "diverged / 1000 random steps",
    ]
    return each_row(head, rec["rows"], cells)


PEERS_CPU2 = tuple(f"peers_cpu2_cartpole_reacher_{i}" for i in (1, 2, 3, 4)) + (
    "peers_cpu2_reacher_1",
    "peers_cpu2_reacher_2",
)

TABLES = {
    "peers-cpu2": Table(PEERS_CPU2, peers_cpu2),
    "gpu-h100": Table(
        ("throughput_h100_lean_vs_full_model", "throughput_h100_reacher_plain_step"), gpu_h100
    ),
    "gpu-h200-modes": Table(("throughput_h200_modes",), throughput_h200),
    "walker-solver": Table(("walker_solver_variants_h100",), walker_solver),
}
