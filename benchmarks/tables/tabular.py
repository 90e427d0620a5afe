"""Tabular agents: Q-learning and SARSA on CartPole-v0, whole cold commands."""

from __future__ import annotations

from .common import Cells, Rec, Row, Table, each_row, secs

AGENTS = {"qlearning": "Q-learning", "sarsa": "SARSA"}


def tabular_cold(recs: list[Rec]) -> Cells:
    (rec,) = recs

    def cells(r: Row) -> list[str]:
        return [
            AGENTS[r["agent"]],
            f"{r['eval_return']} +- {r['eval_std']}",
            f"{secs(r['process_wall_s'])} ({secs(r['train_wall_s'])})",
            f"`jaxenvs train CartPole-v0 --algo {r['agent']} --no-compile-cache "
            "--no-video --quiet`",
        ]

    head = ["agent", "eval return", "whole command wall (train wall)", "command"]
    return each_row(head, rec["rows"], cells)


TABLES = {"tabular-cold": Table(("tabular_cartpole_cold_cpu2",), tabular_cold)}
