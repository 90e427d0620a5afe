"""Contact: the hexapod's heading dependence and step cost per contact setting."""

from __future__ import annotations

from .common import Cells, Rec, Row, Table, each_row, met, rate


def _setting(r: Row) -> str:
    out = f"{r['solver']} {r['cone']} {r['iterations']} / {r['ls_iterations']}"
    extras = []
    if r["impratio"] != 1.0:
        extras.append(f"impratio {r['impratio']:g}")
    if r["noslip_iterations"]:
        extras.append(f"noslip {r['noslip_iterations']}")
    if r["tolerance"] != 1e-8:
        extras.append(f"tolerance {r['tolerance']:g}")
    return ", ".join([out, *extras])


def contact_isotropy(recs: list[Rec]) -> Cells:
    (rec,) = recs

    def cells(r: Row) -> list[str]:
        return [
            _setting(r),
            f"{r['obs_1']:.1e}",
            f"{r['obs_5']:.1e}",
            f"{r['joint_0p6s']:.1e}",
            f"{r['nudge_obs_5']:.1e}",
            f"{r['solver_iters_mean']:.1f} / {r['solver_iters_max']}",
            f"{r['walked_m']:.3f}",
            f"{r['terrain_stand_range_m']:.3f}",
            rate(r["steps_per_cpu_s"]),
            f"{r['cost_vs_today']:.2f}x",
            met(r["isotropic"]),
        ]

    head = [
        "solver, cone, iterations / line search",
        "obs, 1 step",
        "obs, 5 steps",
        "joints at 0.6 s (rad)",
        "obs, 5 steps after a 1e-9 rad nudge",
        "solver iterations (mean / max)",
        "walked in 2 s (m)",
        "torso height range standing on the terrain (m)",
        "mj_step per CPU s",
        "cost",
        "obs within 2e-3 over 5 steps",
    ]
    return each_row(head, rec["rows"], cells)


TABLES = {"contact-isotropy": Table(("contact_isotropy_cpu2",), contact_isotropy)}
