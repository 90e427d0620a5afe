"""Soak: long runs of every task under random and extreme actions."""

from __future__ import annotations

from .common import Cells, Rec, Row, Table, each_row, secs


def soak_h100(recs: list[Rec]) -> Cells:
    (rec,) = recs

    def cells(r: Row) -> list[str]:
        return [
            r["task"],
            f"{r['env_steps']:,}",
            secs(r["wall_s"]),
            f"{r['nonfinite_obs']} / {r['nonfinite_reward']}",
            str(r["diverged"]),
            f"{r['nan_inf_actions']:,}" if r["nan_inf_actions"] else "0 (discrete)",
            f"{r['episodes']:,}",
            f"{r['max_abs_obs']:g}",
            f"{r['rss_first_block_mib']} -> {r['rss_last_mib']}",
        ]

    head = [
        "task",
        "env steps",
        "wall (incl. compile)",
        "non-finite obs / reward",
        "diverged",
        "NaN/inf actions",
        "episodes",
        "max \\|obs\\|",
        "host RSS after 1st block -> last (MiB)",
    ]
    return each_row(head, rec["rows"], cells)


TABLES = {"soak-h100": Table(("soak_h100_all_tasks",), soak_h100)}
