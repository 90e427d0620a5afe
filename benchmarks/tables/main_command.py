"""The main command: ``jaxenvs train`` as the README gives it, cold and warm."""

from __future__ import annotations

from .common import Cells, Rec, Row, Table, each_row, secs


def main_command(recs: list[Rec]) -> Cells:
    (rec,) = recs

    def cells(r: Row) -> list[str]:
        return [
            f"`{r['command']}`",
            "cold" if r["run"] == 0 else f"warm ({r['run']})",
            secs(r["whole_command_s"]),
            secs(r["train_wall_s"]),
            str(r["physics"]),
            f"{r['eval_mean_return']:.1f}",
            "yes" if r["video"] else "no",
        ]

    head = ["command", "run", "whole command", "train wall", "engine", "eval return", "video"]
    return each_row(head, rec["rows"], cells)


TABLES = {"main-command-cpu2": Table(("main_command_cpu2",), main_command)}
