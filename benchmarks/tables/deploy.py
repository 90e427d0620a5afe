"""Deploy: a trained, exported policy driving the simulated robot over its TCP link."""

from __future__ import annotations

from .common import Cells, Rec, Row, Table, each_row, met


def deploy_loop(recs: list[Rec]) -> Cells:
    """The median of each priority's runs, per result file (quiet and busy machine)."""

    def cells(r: Row) -> list[str]:
        target = r["target_period_ms"]
        return [
            f"{r['env_id']}, {r['machine_state']}",
            r["priority"],
            f"{r['median_of']}",
            f"{r['period_ms_mean']:.2f} / {r['period_ms_p99']:.2f} (target {target:g})",
            f"{r['deadline_misses']:g} of {r['steps']:g}",
            f"{r['return']:.1f}",
            str(r["terminated_runs"]),
            met(bool(r["all_pass"])),
        ]

    head = [
        "task, machine",
        "priority",
        "runs (median)",
        "period ms: mean / p99",
        "deadline misses",
        "return",
        "runs ended early",
        "every run within target",
    ]
    rows = [
        {**r, "machine_state": "busy" if rec["name"].endswith("_busy") else "quiet"}
        for rec in recs
        for r in rec["rows"]
        if "median_of" in r
    ]
    return each_row(head, rows, cells)


TABLES = {
    "deploy-loop": Table(
        (
            "deploy_cpu2_cartpole",
            "deploy_cpu2_cartpole_busy",
            "deploy_cpu2_reacher",
            "deploy_cpu2_reacher_busy",
        ),
        deploy_loop,
    ),
}
