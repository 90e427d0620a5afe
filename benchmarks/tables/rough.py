"""Rough ground: HexapodJoystickRough-v0 per seed, its curriculum level and its tracking and
falls at the terrain's middle and top level on each engine, against the issue's targets;
HexapodWalkRough-v0 per seed, its level, speed, targets and falls (no targets set)."""

from __future__ import annotations

from .common import HFIELD_COLLIDERS, Cells, Rec, Row, Table, each_row, met, pct

#: (row field, label) of each engine group a row may hold
BENCHES = (
    ("mjx", "MJX"),
    ("mjx_randomized", "MJX, randomised"),
    ("mujoco_c", "MuJoCo C"),
    ("mujoco_c_randomized", "C, randomised"),
    ("mujoco_c_prisms", "C, MuJoCo's heightfield collider"),
)
#: the targets at the middle level: falls, linear and yaw RMS tracking errors
MID_FELL, MID_LIN, MID_YAW = 0.05, 0.15, 0.30
#: the final mean level over the top level's index
LEVEL_SHARE = 0.6


def _figures(g: Row) -> str:
    return (
        f"{g['tracking_error_lin']:.3f} / {g['tracking_error_yaw']:.3f} / {pct(g['fell_fraction'])}"
    )


def _mid_met(g: Row) -> bool:
    return (
        g["fell_fraction"] <= MID_FELL
        and g["tracking_error_lin"] <= MID_LIN
        and g["tracking_error_yaw"] <= MID_YAW
    )


def _run_cells(r: Row) -> list[str]:
    """A terrain run's seed, train wall, chunks and first chunk's mean level."""
    done = "" if r["finished"] else " (stopped)"
    return [
        str(r["seed"]),
        f"{r['train_seconds']:.1f} s",
        f"{r['chunks']} / {r['num_chunks']}{done}",
        f"{r['first_chunk_mean_level']:.2f}",
    ]


def rough_training(recs: list[Rec]) -> Cells:
    """Per seed: the train wall and chunks, the mean level in the first and last chunk, and
    whether the wall (<= 600 s) and the level (>= 0.6 x (levels - 1)) targets are met."""
    (rec,) = recs

    def cells(r: Row) -> list[str]:
        bar = LEVEL_SHARE * (r["levels"] - 1)
        return [
            *_run_cells(r),
            f"{r['final_mean_level']:.2f}",
            f"{bar:.1f}",
            met(r["train_seconds"] <= 600 and r["finished"]),
            met(r["final_mean_level"] >= bar),
        ]

    head = [
        "seed",
        "train wall",
        "chunks",
        "mean level, first chunk",
        "mean level, last chunk",
        "level target",
        "whole run <= 600 s",
        "level target met",
    ]
    return each_row(head, sorted(rec["rows"], key=lambda r: r["seed"]), cells)


def rough_probes(recs: list[Rec]) -> Cells:
    """One row per run of each record (a probe's rows name what it changed in ``probe``;
    rows without one are the config shipped then, 4,096 envs x 32 steps): the train wall
    and chunks, the last chunk's mean level, and the middle level's tracking and falls
    under MuJoCo C with default and randomised physics. Train walls are as each record's
    machine says (a host to itself or shared: the first chunk's compile differs)."""

    def cells(r: Row) -> list[str]:
        c, rand = r["mujoco_c"]["mid"], r["mujoco_c_randomized"]["mid"]
        return [
            r.get("probe", "4096 envs x 32 steps (shipped then)"),
            *_run_cells(r)[:3],
            f"{r['final_mean_level']:.2f}",
            _figures(c),
            _figures(rand),
        ]

    head = [
        "probe",
        "seed",
        "train wall",
        "chunks",
        "mean level, last chunk",
        "C mid: lin m/s / yaw rad/s / fell",
        "C, randomised mid",
    ]
    return each_row(head, [r for rec in recs for r in rec["rows"]], cells)


def rough_tracking(recs: list[Rec]) -> Cells:
    """Per seed and engine group: RMS tracking errors and falls at the middle and the top
    level, and whether the middle level meets its targets."""
    (rec,) = recs

    def cells(rb: tuple[Row, str, str]) -> list[str]:
        r, field, label = rb
        g = r[field]
        return [
            str(r["seed"]),
            label,
            _figures(g["mid"]),
            _figures(g["top"]),
            met(_mid_met(g["mid"])),
        ]

    head = [
        "seed",
        "engine",
        "mid: lin m/s / yaw rad/s / fell",
        "top: lin m/s / yaw rad/s / fell",
        f"mid within {MID_LIN} m/s, {MID_YAW} rad/s, {pct(MID_FELL)} falls",
    ]
    found = [
        (r, field, label)
        for r in sorted(rec["rows"], key=lambda r: r["seed"])
        for field, label in BENCHES
        if field in r
    ]
    return each_row(head, found, cells)


def walker_rough_training(recs: list[Rec]) -> Cells:
    """Per seed: the train wall and chunks, the mean level in the first and last chunk."""
    (rec,) = recs

    def cells(r: Row) -> list[str]:
        return [*_run_cells(r), f"{r['final_mean_level']:.2f} of {r['levels'] - 1}"]

    head = ["seed", "train wall", "chunks", "mean level, first chunk", "mean level, last chunk"]
    return each_row(head, sorted(rec["rows"], key=lambda r: r["seed"]), cells)


def walker_rough_walking(recs: list[Rec]) -> Cells:
    """Per seed and engine group: speed toward the target, targets a minute and falls at
    the middle and the top level, and the middle level's falls per terrain type."""
    (rec,) = recs
    rows = sorted(rec["rows"], key=lambda r: r["seed"])
    types = list(next(r[f] for r in rows for f, _ in BENCHES if f in r)["mid_fell_by_type"])

    def walk(g: Row) -> str:
        return f"{g['speed']:.2f} / {g['targets_per_minute']:.1f} / {pct(g['fell_fraction'])}"

    def cells(rb: tuple[Row, str, str]) -> list[str]:
        r, field, label = rb
        g = r[field]
        by_type = " / ".join(pct(g["mid_fell_by_type"][t]) for t in types)
        return [str(r["seed"]), label, walk(g["mid"]), walk(g["top"]), by_type]

    head = [
        "seed",
        "engine",
        "mid: m/s / targets a minute / fell",
        "top: m/s / targets a minute / fell",
        f"mid falls by type ({' / '.join(types)})",
    ]
    found = [(r, field, label) for r in rows for field, label in BENCHES if field in r]
    return each_row(head, found, cells)


def hfield_normals(recs: list[Rec]) -> Cells:
    """Per engine setting and band of penetration: the share of foot placements on a flat
    heightfield with a contact normal below 0.99 vertical, the lowest, the contacts."""
    (rec,) = recs

    def cells(r: Row) -> list[str]:
        lo, hi = r["band_mm"]
        return [
            r["engine"],
            f"{lo:.0f}-{hi:.0f} mm",
            str(r["placements"]),
            pct(r["share_below_0_99"]),
            f"{r['lowest_normal_z']:.3f}",
            f"{r['mean_contacts']:.1f}",
        ]

    head = [
        "engine",
        "penetration",
        "placements",
        "with a normal below 0.99 vertical",
        "lowest normal z",
        "contacts (mean)",
    ]
    return each_row(head, rec["rows"], cells)


def flat_ground(recs: list[Rec]) -> Cells:
    """Per engine and ground: one terrain policy's falls and its walking (speed, targets a
    minute) or tracking (linear, yaw RMS errors) on flat ground made three ways."""
    rows = [r for rec in recs for r in rec["rows"]]
    walker = "speed" in rows[0]

    def collider(r: Row) -> str:
        """MuJoCo C's heightfield collider (rows before the choice existed: MuJoCo's)."""
        if r["physics"] != "c" or r["ground"] == "plane":
            return "-"
        return HFIELD_COLLIDERS[r.get("hfield_contact", "mujoco")]

    def cells(r: Row) -> list[str]:
        if walker:
            figures = [f"{r['speed']:.2f}", f"{r['targets_per_minute']:.1f}"]
        else:
            figures = [f"{r['tracking_error_lin']:.3f}", f"{r['tracking_error_yaw']:.3f}"]
        return [
            r["physics"],
            r["ground"],
            collider(r),
            str(r["envs"]),
            pct(r["fell_fraction"]),
            *figures,
        ]

    named = (
        ["m/s toward the target", "targets a minute"]
        if walker
        else ["lin error RMS (m/s)", "yaw error RMS (rad/s)"]
    )
    head = ["engine", "ground", "C heightfield collider", "envs", "fell in 20 s", *named]
    return each_row(head, rows, cells)


def stones_falls(recs: list[Rec]) -> Cells:
    """Falls on stepping-stone tiles per run, pit and level (benchmarks/stones_falls.py)."""
    (rec,) = recs

    def cells(r: Row) -> list[str]:
        pit = "levelled" if r["pit"] == "levelled" else f"{float(r['pit']):.2f} m"
        return [
            f"{r['run']} (seed {r['seed']})",
            pit,
            str(r["level"]),
            f"{100 * r['pit_depth']:.1f} cm",
            f"{100 * r['stone_size']:.1f} / {100 * r['stone_gap']:.1f} cm",
            f"{r['envs']} x {r['seconds']:.0f} s",
            pct(r["fell_fraction"]),
        ]

    head = ["policy", "pit", "level", "pit depth", "stone / gap", "envs x episode", "fell"]
    return each_row(head, rec["rows"], cells)


TABLES = {
    "stones-falls": Table(("stones_falls_cpu2",), stones_falls),
    "walker-ground": Table(
        ("walker_ground_cpu2", "walker_ground_cpu2_surface", "walker_ground_cpu2_mjx"), flat_ground
    ),
    "joystick-ground": Table(
        ("joystick_ground_cpu2", "joystick_ground_cpu2_surface", "joystick_ground_cpu2_mjx"),
        flat_ground,
    ),
    "hfield-normals": Table(("hfield_normals_cpu2",), hfield_normals),
    "walker-rough-training": Table(("ppo_walker_rough_seeds_h200",), walker_rough_training),
    "walker-rough-walking": Table(("ppo_walker_rough_seeds_h200",), walker_rough_walking),
    "walker-rough-training-pit20": Table(
        ("ppo_walker_rough_seeds_pit20_h200",), walker_rough_training
    ),
    "walker-rough-walking-pit20": Table(
        ("ppo_walker_rough_seeds_pit20_h200",), walker_rough_walking
    ),
    "rough-training-cg": Table(("ppo_joystick_rough_seeds_cg_h200",), rough_training),
    "rough-tracking-cg": Table(("ppo_joystick_rough_seeds_cg_h200",), rough_tracking),
    "rough-training-c6": Table(("ppo_joystick_rough_seeds_c6_h200",), rough_training),
    "rough-tracking-c6": Table(("ppo_joystick_rough_seeds_c6_h200",), rough_tracking),
    "rough-training-sag-seeds": Table(("ppo_joystick_rough_seeds_sag_h200",), rough_training),
    "rough-training-w200": Table(("ppo_joystick_rough_seeds_w200_h200",), rough_training),
    "rough-probes-w200": Table(("ppo_joystick_rough_seeds_w200_h200",), rough_probes),
    "rough-probes-link": Table(("ppo_joystick_rough_link_h200",), rough_probes),
    "rough-tracking-link": Table(("ppo_joystick_rough_link_h200",), rough_tracking),
    "rough-tracking-sag-seeds": Table(("ppo_joystick_rough_seeds_sag_h200",), rough_tracking),
    "rough-training-gait-seeds": Table(("ppo_joystick_rough_seeds_gait_h200",), rough_training),
    "rough-tracking-gait-seeds": Table(("ppo_joystick_rough_seeds_gait_h200",), rough_tracking),
    "rough-training-wide": Table(("ppo_joystick_rough_seeds_wide_h200",), rough_training),
    "rough-tracking-wide": Table(("ppo_joystick_rough_seeds_wide_h200",), rough_tracking),
    "rough-training": Table(("ppo_joystick_rough_seeds_h200",), rough_training),
    "rough-tracking": Table(("ppo_joystick_rough_seeds_h200",), rough_tracking),
    "rough-training-pit20": Table(("ppo_joystick_rough_seeds_pit20_h200",), rough_training),
    "rough-tracking-pit20": Table(("ppo_joystick_rough_seeds_pit20_h200",), rough_tracking),
    "rough-training-newton": Table(("ppo_joystick_rough_seeds_newton_h200",), rough_training),
    "rough-tracking-newton": Table(("ppo_joystick_rough_seeds_newton_h200",), rough_tracking),
    "rough-training-clearance": Table(("ppo_joystick_rough_clearance_h200",), rough_training),
    "rough-tracking-clearance": Table(("ppo_joystick_rough_clearance_h200",), rough_tracking),
    "rough-probes-dec02": Table(
        (
            "ppo_joystick_rough_seeds_h200",
            "ppo_joystick_rough_history5_h200",
            "ppo_joystick_rough_history15_h200",
            "ppo_joystick_rough_wide_h200",
        ),
        rough_probes,
    ),
    "rough-probes-gait": Table(
        (
            "ppo_joystick_rough_gait_h200",
            "ppo_joystick_rough_gait_prior_h200",
            "ppo_joystick_rough_gait_prior_cut_h200",
            "ppo_joystick_rough_gait_lift50_h200",
        ),
        rough_probes,
    ),
    "rough-training-gait-prior": Table(("ppo_joystick_rough_gait_prior_h200",), rough_training),
    "rough-tracking-gait-prior": Table(("ppo_joystick_rough_gait_prior_h200",), rough_tracking),
    "rough-training-h100": Table(("ppo_joystick_rough_seed0_cut_h100",), rough_training),
    "rough-tracking-h100": Table(("ppo_joystick_rough_seed0_cut_h100",), rough_tracking),
}
