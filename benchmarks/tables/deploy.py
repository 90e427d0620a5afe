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


#: the heads of a drive's figures (the cells: :func:`_drive_cells`)
_DRIVE_HEAD = [
    "lin error RMS (m/s)",
    "yaw error RMS (rad/s)",
    "falls",
    "period p99 (ms)",
    "round trip p50 (ms)",
    "within 1.5x the simulation's errors, no fall",
]


def _drive_cells(r: Row, falls: str, passed: bool) -> list[str]:
    return [
        f"{r['lin_rms']:.3f}",
        f"{r['yaw_rms']:.3f}",
        falls,
        f"{r['period_ms_p99']:.1f}",
        f"{r['round_trip_ms_p50']:.0f}",
        met(passed),
    ]


def deploy_joystick(recs: list[Rec]) -> Cells:
    """HexapodJoystick-v0 through the link, one line per link setting (median of its runs)."""

    def cells(r: Row) -> list[str]:
        link = (
            "ideal (no delay, no noise)"
            if not (r["latency_ms"] or r["jitter_ms"] or r["noise"])
            else f"{r['latency_ms']:g} + [0, {r['jitter_ms']:g}] ms, noise {r['noise']:g}"
        )
        return [link, f"{r['median_of']}", *_drive_cells(r, f"{r['falls']}", r["all_pass"])]

    head = ["link: latency + jitter, sensor noise", "runs (median)", *_DRIVE_HEAD]
    rows = [r for rec in recs for r in rec["rows"] if "median_of" in r]
    return each_row(head, rows, cells)


def deploy_rough_types(recs: list[Rec]) -> Cells:
    """HexapodJoystickRough-v0 through the link, one 60 s drive per terrain tile."""

    def cells(r: Row) -> list[str]:
        return [r["terrain"], *_drive_cells(r, "yes" if r["fell"] else "no", r["passes"])]

    head = ["tile (level:type)", *_DRIVE_HEAD]
    rows = [r for rec in recs for r in rec["rows"] if "median_of" not in r]
    return each_row(head, rows, cells)


TABLES = {
    "deploy-joystick": Table(("deploy_cpu2_joystick",), deploy_joystick),
    "deploy-joystick-filter": Table(("deploy_cpu2_joystick_filter",), deploy_joystick),
    "deploy-joystick-rough": Table(("deploy_cpu2_joystick_rough",), deploy_joystick),
    "deploy-joystick-rough-wide": Table(("deploy_cpu2_joystick_rough_wide",), deploy_joystick),
    "deploy-joystick-rough-gait": Table(("deploy_cpu2_joystick_rough_gait",), deploy_joystick),
    "deploy-joystick-rough-sag": Table(("deploy_cpu2_joystick_rough_sag",), deploy_joystick),
    "deploy-joystick-rough-c6": Table(("deploy_cpu2_joystick_rough_c6",), deploy_joystick),
    "deploy-joystick-rough-c6-s1": Table(("deploy_cpu2_joystick_rough_c6_s1",), deploy_joystick),
    "deploy-joystick-rough-c6-s2": Table(("deploy_cpu2_joystick_rough_c6_s2",), deploy_joystick),
    "deploy-joystick-rough-link": Table(("deploy_cpu2_joystick_rough_link",), deploy_joystick),
    "deploy-joystick-rough-types": Table(("deploy_cpu2_joystick_rough_types",), deploy_rough_types),
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
