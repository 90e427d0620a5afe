"""Gymnasium facade: our ``gymnasium.make`` / ``make_vec`` envs against Gymnasium's own."""

from __future__ import annotations

from .common import Cells, Rec, Table, rate, ratio, rows, secs


def facade(recs: list[Rec]) -> Cells:
    """One env and a vector env each: every contender's best round, ours over each peer."""
    (rec,) = recs
    cells = [["mode", "who", "envs", "steps/s (best of rounds)", "ours / peer(s)", "first call"]]
    for mode in ("single", "vector"):
        found = rows(rec, mode=mode)
        peers = [max(r["steps_per_s_rounds"]) for r in found if not r["who"].startswith("ours")]
        for r in found:
            b = max(r["steps_per_s_rounds"])
            against = " / ".join(f"**{ratio(b, p)}**" for p in peers)  # in the peers' order
            cells.append(
                [
                    "one env" if mode == "single" else "vector",
                    r["who"],
                    str(r["num_envs"]),
                    rate(b),
                    against if r["who"].startswith("ours") else "",
                    secs(r["first_call_s"]) if r["first_call_s"] is not None else "",
                ]
            )
    return cells


TABLES = {
    "facade-c": Table(("facade_cpu2_reacher_c",), facade),
    "facade-native": Table(("facade_cpu2_native",), facade),
    "facade-single-idle": Table(("facade_cpu2_single_idle",), facade),
    "facade-single-struct": Table(("facade_cpu2_single_struct",), facade),
    "facade-single-fast": Table(("facade_cpu2_single_fast",), facade),
    "facade-single-dec02": Table(("facade_cpu2_single_dec02",), facade),
}
