"""Training: PPO per task against its target, the walker's seeds, whole cold commands on
each engine, and policies trained on one engine evaluated under both."""

from __future__ import annotations

import statistics
from collections.abc import Callable

from .common import Cells, Rec, Row, Table, each_row, met, pct, ret, rows, secs

PPO_HEAD = [
    "id",
    "seeds",
    "eval per seed",
    "env steps / seed",
    "train / process wall",
    "where",
    "target",
    "met?",
]


def _engine(physics: str) -> str:
    return "C" if physics == "c" else "MJX"


def _walls(r: Row) -> str:
    return ", ".join(
        f"{t} / {p} s" for t, p in zip(r["train_wall_s"], r["process_wall_s"], strict=True)
    )


def _where(rec: Rec) -> str:
    m = rec["machine"]
    return m["gpu"] or f"{m['cores']} CPU cores"


def _floats(xs: list[float]) -> str:
    return ", ".join(f"{x:.2f}" for x in xs)


def ppo_cold_cpu2(recs: list[Rec]) -> Cells:
    (rec,) = recs
    cells = [["load average", "engine", "whole command, cold"]]
    for load in dict.fromkeys(r["load"] for r in rec["rows"]):
        for engine in ("c", "mjx"):
            found = rows(rec, load=load, engine=engine)
            walls = ", ".join(secs(r["process_wall_s"]) for r in found)
            cells.append([load, _engine(engine), walls])
    return cells


def ppo_cold_cpu16(recs: list[Rec]) -> Cells:
    (rec,) = recs

    def cells(r: Row) -> list[str]:
        engine = "C, 16 threads (the default)" if r["engine"] == "c" else "MJX"
        return [engine, str(r["devices"]), secs(r["process_wall_s"])]

    head = ["engine", "devices", "whole command, cold (`--no-compile-cache`)"]
    return each_row(head, rec["rows"], cells)


def cross_engine(recs: list[Rec]) -> Cells:
    (rec,) = recs

    def cells(r: Row) -> list[str]:
        end = r["train_eval_return"]
        return [
            r["env_id"],
            _engine(r["trained_physics"]),
            secs(r["train_wall_s"]),
            f"{r['env_steps']:,}",
            f"{end:.{2 if abs(end) < 100 else 1}f}",
            ret(r["eval_mjx"], r["eval_mjx_std"]),
            ret(r["eval_c"], r["eval_c_std"]),
        ]

    head = [
        "id",
        "trained on",
        "train wall",
        "env steps",
        "eval at the end of training",
        "eval under MJX",
        "eval under C",
    ]
    return each_row(head, rec["rows"], cells)


def _cartpole_row(rec: Rec) -> list[str]:
    """CartPole-v0's line: every cold and warm run of the same seed."""
    cold, warm = rows(rec, cache="cold"), rows(rec, cache="warm")

    def cw(found: list[Row]) -> str:
        return ", ".join(f"{r['train_wall_s']} / {r['process_wall_s']}" for r in found) + " s"

    cold_ok = sum(r["train_wall_s"] <= 30 for r in cold)
    return [
        "CartPole-v0",
        "0",
        f"{statistics.median(r['eval'] for r in cold + warm):g} (every run)",
        "131,072",
        f"cold {cw(cold)}; warm {cw(warm)}",
        _where(rec),
        ">= 475; <= 30 s cold, <= 10 s warm",
        f"return yes; warm {met(all(r['process_wall_s'] <= 10 for r in warm))}; "
        f"cold: train wall in {cold_ok} of {len(cold)} rounds, process wall "
        f"{met(all(r['process_wall_s'] <= 30 for r in cold))}",
    ]


def _seeds_row(rec: Rec, r: Row, evals: str) -> list[str]:
    """A line of several seeds of one config on one machine."""
    return [
        r["env_id"],
        r["seeds"],
        evals,
        f"{r['env_steps']:,}",
        _walls(r),
        _where(rec),
        r["target"] or "",
        r["met"] or "",
    ]


def _walker_row(rec: Rec) -> list[str]:
    """HexapodWalk-v0's line: the shipped config's seeds (waypoints, 24 chunks)."""
    shipped = [r for r in rec["rows"] if r["config_diff"] == {}]
    ok = all(
        r["speed_m_per_s"] >= 0.5
        and r["fell_fraction"] <= 0.05
        and r["targets_reached"] >= 0.9
        and r["train_seconds"] <= 600
        for r in shipped
    )
    return [
        "HexapodWalk-v0",
        ", ".join(str(r["seed"]) for r in shipped),
        "eval return "
        + ", ".join(f"{r['eval_mean_return']:.1f}" for r in shipped)
        + "; greedy speed to a far target "
        + ", ".join(f"{r['speed_m_per_s']:.3f}" for r in shipped)
        + " m/s; fell in 10 s "
        + ", ".join(pct(r["fell_fraction"]) for r in shipped)
        + "; 3 m targets reached "
        + ", ".join(pct(r["targets_reached"]) for r in shipped),
        f"{shipped[0]['env_steps']:,}",
        ", ".join(f"{r['train_seconds']:.1f} / {r['process_wall_s']} s" for r in shipped),
        _where(rec),
        ">= 0.5 m/s on one GPU in 10 min; <= 5% fallen in 10 s; >= 90% of 3 m targets",
        met(ok) + " on every seed",
    ]


def ppo(recs: list[Rec]) -> Cells:
    cold_warm, cpu2, oneleg, walker = recs
    cells = [PPO_HEAD, _cartpole_row(cold_warm)]
    cells += [_seeds_row(cpu2, r, ", ".join(r["eval_return"])) for r in cpu2["rows"]]
    (r,) = oneleg["rows"]
    tip = (
        f"final tip error (100 greedy episodes): mean {_floats(r['final_tip_error_cm_mean'])}"
        f" cm (median {_floats(r['final_tip_error_cm_median'])} cm)"
    )
    cells.append(_seeds_row(oneleg, r, tip))
    cells.append(_walker_row(walker))
    return cells


def _walker_label(r: Row) -> tuple[int, str]:
    """Where a walker run of the far-target configs sorts and what config it ran: before,
    v1 or the 80-chunk one (shipped until the waypoints)."""
    diff = r["config_diff"]
    if not diff:
        return 2, "far targets, 80 chunks"
    if diff.get("agent.randomize") is False:
        return 0, "before (the earlier config)"
    return 1, "v1 (upright terms, randomised training, `ent_coef` 0.01, 112 chunks)"


def _walker_figures(g: Row) -> str:
    """Speed, fell within 10 s / over the 50 s episode (far target), 3 m targets reached,
    and the 3 m group's falls over the episode; the last two falls where the record has
    them."""

    def ep(key: str) -> str:
        return pct(g[key]) if key in g else "-"

    return (
        f"{g['speed_m_per_s']:.3f} / {pct(g['fell_fraction'])} / "
        f"{ep('fell_fraction_episode')} / {pct(g['targets_reached'])} / "
        f"{ep('fell_fraction_episode_near')}"
    )


def walker_seeds(recs: list[Rec]) -> Cells:
    (rec,) = recs

    def cells(r: Row) -> list[str]:
        process = f" / {r['process_wall_s']} s" if "process_wall_s" in r else " s"
        return [
            f"{_walker_label(r)[1]}, {r['seed']}" + (" (*)" if "recovered" in r else ""),
            f"{r['train_seconds']:.1f}{process}, {r['env_steps'] / 1e6:.1f}M",
            _walker_figures(r),
            _walker_figures(r["randomized"]),
            _walker_figures(r["mujoco_c"]),
            _walker_figures(r["mujoco_c_randomized"]),
        ]

    head = [
        "config, seed",
        "train / process wall, env steps",
        "MJX: speed / fell 10 s / fell 50 s / 3 m reached / 3 m fell 50 s",
        "randomised",
        "MuJoCo C",
        "C, randomised",
    ]
    order = sorted(rec["rows"], key=lambda r: (_walker_label(r)[0], r["seed"]))
    return each_row(head, order, cells)


def _waypoint_figures(g: Row) -> str:
    """Speed and falls within 10 s (far target); 3 m targets: the first reached, targets
    per minute and the falls over the 50 s episode of walking from target to target."""
    return (
        f"{g['speed_m_per_s']:.3f} / {pct(g['fell_fraction'])} / "
        f"{pct(g['targets_reached'])} / {g['targets_per_minute']:.1f} / "
        f"{pct(g['fell_fraction_episode_near'])}"
    )


def _per_seed(
    rec: Rec, first: str, groups: tuple[str, ...], figures: Callable[[Row], str]
) -> Cells:
    """One row per seed: its train wall (first chunk) and env steps, then ``figures`` of
    each of ``groups`` (the row's fields, or the row itself where a group is ``""``), MJX
    and MuJoCo C, default and randomised physics; ``first``: the MJX column's head."""

    def cells(r: Row) -> list[str]:
        return [
            str(r["seed"]),
            f"{r['train_seconds']:.1f} s ({r['first_chunk_seconds']:.1f} s first chunk), "
            f"{r['env_steps'] / 1e6:.1f}M",
            *(figures(r[g] if g else r) for g in groups),
        ]

    head = ["seed", "train wall, env steps", first, "MJX, randomised", "MuJoCo C", "C, randomised"]
    return each_row(head, sorted(rec["rows"], key=lambda r: r["seed"]), cells)


def walker_waypoints(recs: list[Rec]) -> Cells:
    """HexapodWalk-v0 with waypoints, per seed: both engines, default and drawn physics."""
    (rec,) = recs
    first = "MJX: speed / fell 10 s / 3 m reached / targets per min / fell 50 s at 3 m"
    groups = ("", "randomized", "mujoco_c", "mujoco_c_randomized")
    return _per_seed(rec, first, groups, _waypoint_figures)


def walker_variants(recs: list[Rec]) -> Cells:
    """HexapodWalk-v0 variants, one row per run: what it changed against the shipped
    config (``config_diff``), then the waypoint figures on both engines."""
    (rec,) = recs

    def label(r: Row) -> str:
        diff = r["config_diff"]
        parts = [f"{k.split('.')[-1]} {v}" for k, v in sorted(diff.items())]
        return f"{r['seed']}: " + (", ".join(parts) or "the shipped config")

    def cells(r: Row) -> list[str]:
        return [
            label(r),
            f"{r['train_seconds']:.1f} s ({r['first_chunk_seconds']:.1f} s first chunk)",
            *(
                _waypoint_figures(r[g] if g else r)
                for g in ("", "randomized", "mujoco_c", "mujoco_c_randomized")
            ),
        ]

    head = [
        "seed: variant",
        "train wall",
        "MJX: speed / fell 10 s / 3 m reached / targets per min / fell 50 s at 3 m",
        "MJX, randomised",
        "MuJoCo C",
        "C, randomised",
    ]
    order = sorted(rec["rows"], key=lambda r: (r["env_steps"], r["seed"]))
    return each_row(head, order, cells)


def walker_eval_wide(recs: list[Rec]) -> Cells:
    """Policies' waypoint evals with more envs, per policy and group: speed (far), falls
    within 10 s (far) and over the 50 s episode (both), 3 m targets per minute."""
    (rec,) = recs
    groups = ("default_far", "default_near", "randomized_far", "randomized_near")

    def cells(rg: tuple[Row, str]) -> list[str]:
        r, g = rg
        x = r[g]
        speed = f"{x['speed_m_per_s']:.3f}" if "speed_m_per_s" in x else "-"
        within = pct(x["fell_fraction"]) if "fell_fraction" in x else "-"
        per_min = f"{x['targets_per_minute']:.1f}" if "targets_per_minute" in x else "-"
        falls = pct(x["fell_fraction_episode"])
        who = f"{r['seed']}, {r['physics']} ({r['device']})"
        return [who, g, str(r["envs_per_group"]), speed, within, falls, per_min]

    head = ["seed, engine", "group", "envs", "speed m/s", "fell in 10 s", "fell over 50 s"]
    head.append("targets per min")
    return each_row(head, [(r, g) for r in rec["rows"] for g in groups], cells)


def _joystick_figures(g: Row) -> str:
    fell = g["fell_fraction"] * 100
    return f"{g['tracking_error_lin']:.3f} / {g['tracking_error_yaw']:.3f} / {fell:.1f}%"


def joystick_seeds(recs: list[Rec]) -> Cells:
    """HexapodJoystick-v0 per seed: RMS tracking errors and falls on both engines."""
    (rec,) = recs
    groups = ("mjx", "mjx_randomized", "mujoco_c", "mujoco_c_randomized")
    return _per_seed(rec, "MJX: lin m/s / yaw rad/s / fell", groups, _joystick_figures)


def joystick_variants(recs: list[Rec]) -> Cells:
    """HexapodJoystick-v0 variants of one seed, one row per run (its ``variant``)."""
    (rec,) = recs
    groups = ("mjx", "mjx_randomized", "mujoco_c", "mujoco_c_randomized")

    def cells(r: Row) -> list[str]:
        return [
            f"{r['seed']}: {r['variant']}",
            f"{r['train_seconds']:.1f} s ({r['first_chunk_seconds']:.1f} s first chunk)",
            *(_joystick_figures(r[g]) for g in groups),
        ]

    head = [
        "seed: variant",
        "train wall",
        "MJX: lin m/s / yaw rad/s / fell",
        "MJX, randomised",
        "MuJoCo C",
        "C, randomised",
    ]
    return each_row(head, rec["rows"], cells)


TABLES = {
    "ppo-cold-cpu2": Table(("ppo_cartpole_cold_cpu2_engines",), ppo_cold_cpu2),
    "cross-engine": Table(("cross_engine_ppo_cpu2",), cross_engine),
    "ppo-cold-cpu16": Table(("ppo_cartpole_cold_cpu16_engines",), ppo_cold_cpu16),
    "ppo": Table(
        (
            "ppo_cartpole_cpu2_cold_warm",
            "ppo_cpu2_cartpoles_reacher",
            "ppo_cpu2_oneleg",
            "ppo_walker_waypoints_h200",
        ),
        ppo,
    ),
    "walker-seeds": Table(("ppo_walker_seeds_h200",), walker_seeds),
    "walker-waypoints": Table(("ppo_walker_waypoints_pyramidal_h200",), walker_waypoints),
    "walker-waypoints-elliptic": Table(("ppo_walker_waypoints_h200",), walker_waypoints),
    "walker-waypoints-staged": Table(("ppo_walker_staged_h200",), walker_waypoints),
    "walker-waypoints-before": Table(("ppo_walker_waypoints_h100",), walker_waypoints),
    "walker-waypoints-gpus2": Table(("ppo_walker_waypoints_gpus2_h200",), walker_waypoints),
    "walker-waypoints-gpus1": Table(("ppo_walker_waypoints_gpus1_h200",), walker_waypoints),
    "walker-variants": Table(("ppo_walker_variants_h200",), walker_variants),
    "walker-contact": Table(("ppo_walker_contact_h100",), walker_variants),
    "walker-eval-wide": Table(("walker_waypoints_wide",), walker_eval_wide),
    "joystick-variants": Table(("ppo_joystick_variants_h200",), joystick_variants),
    "joystick-contact": Table(("ppo_joystick_contact_h100",), joystick_variants),
    "joystick-seeds-lr": Table(("ppo_joystick_seeds_lr6e4_h100",), joystick_seeds),
    "joystick-seeds-critic": Table(("ppo_joystick_seeds_h100",), joystick_seeds),
    "joystick-seeds-filter": Table(("ppo_joystick_seeds_pyramidal_h200",), joystick_seeds),
    "joystick-seeds-elliptic": Table(("ppo_joystick_seeds_h200",), joystick_seeds),
    "joystick-seeds": Table(("ppo_joystick_seeds_nocritic_h200",), joystick_seeds),
    "joystick-seeds-gap": Table(("ppo_joystick_seeds_gap_h100",), joystick_seeds),
    "joystick-seeds-gpus2": Table(("ppo_joystick_seeds_gpus2_h200",), joystick_seeds),
    "joystick-seeds-gpus1": Table(("ppo_joystick_seeds_gpus1_h200",), joystick_seeds),
}
