"""The main command: ``jaxenvs train`` as the README gives it, cold and warm, beside SB3."""

from __future__ import annotations

import statistics

from .common import Cells, Rec, Row, Table, each_row, secs


def main_command(recs: list[Rec]) -> Cells:
    (rec,) = recs

    def cells(r: Row) -> list[str]:
        sb3 = r["which"].startswith("sb3")
        ret = r["eval_mean_return"]
        xla = ", XLA's defaults" if r["which"].endswith("_xla_defaults") else ""
        xla = ", init compiled optimised" if r["which"].endswith("_optimised_init") else xla
        xla = ", chunk at XLA's default level" if r["which"].endswith("_o2_chunk") else xla
        return [
            f"`{r['command']}`{xla}" if not sb3 else r["command"],
            str(r.get("round", 0)),
            "-" if sb3 else "cold" if r["run"] == 0 else "warm",
            secs(r["whole_command_s"]),
            "-" if sb3 else secs(r["train_wall_s"]),
            "torch" if sb3 else str(r["physics"]),
            "-" if ret is None else f"{ret:.1f}",
            "no" if sb3 else "yes" if r["video"] else "no",
        ]

    head = ["command", "round", "run", "whole process", "train wall", "engine", "eval return"]
    return each_row([*head, "video"], rec["rows"], cells)


def main_command_ratios(recs: list[Rec], bars: tuple[str, str] = ("<= 0.25x", "<= 0.12x")) -> Cells:
    """Median whole-process seconds over the rounds, and each as a multiple of SB3's (and of
    SB3's with its default hyperparameters, where the record has that row); ``bars``: the
    targets of the main command cold and warm (the first issue's by default)."""
    (rec,) = recs
    med = rec["extra"]["median_whole_command_s"]
    sb3, sb3_defaults = med["sb3_0"], med.get("sb3_defaults_0")
    names = {
        "main_0": ("`jaxenvs train CartPole-v0 --algo ppo`, cold", bars[0]),
        "main_1": ("`jaxenvs train CartPole-v0 --algo ppo`, warm", bars[1]),
        "c_no_video_0": ("the same, `--physics c --no-video`, cold", ""),
        "c_no_video_1": ("the same, `--physics c --no-video`, warm", ""),
        "main_xla_defaults_0": ("the main command with XLA's default emitters, cold", ""),
        "main_xla_defaults_1": ("the main command with XLA's default emitters, warm", ""),
        "c_no_video_xla_defaults_0": ("`--physics c --no-video`, XLA's defaults, cold", ""),
        "c_no_video_xla_defaults_1": ("`--physics c --no-video`, XLA's defaults, warm", ""),
        "main_optimised_init_0": ("the main command, its init compiled optimised, cold", ""),
        "main_optimised_init_1": ("the main command, its init compiled optimised, warm", ""),
        "c_no_video_optimised_init_0": ("`--physics c --no-video`, init optimised, cold", ""),
        "c_no_video_optimised_init_1": ("`--physics c --no-video`, init optimised, warm", ""),
        # rows of main_command_cpu2_o1_chunk.json, whose arm (--o2-chunk) the benchmark
        # had only while the chunk around the C engine was compiled at -O1 (reverted)
        "main_o2_chunk_0": ("the main command, its chunk at XLA's default level, cold", ""),
        "main_o2_chunk_1": ("the main command, its chunk at XLA's default level, warm", ""),
        "c_no_video_o2_chunk_0": ("`--physics c --no-video`, chunk at the default, cold", ""),
        "c_no_video_o2_chunk_1": ("`--physics c --no-video`, chunk at the default, warm", ""),
        "sb3_0": ("SB3 PPO, CartPole-v1 to a greedy 500", ""),
        "sb3_defaults_0": ("the same with SB3's default hyperparameters (one env)", ""),
    }
    head = ["run", "median whole process", "/ SB3"]
    rows = [[*head, "/ SB3 defaults", "target"] if sb3_defaults else [*head, "target"]]
    for key, (what, bar) in names.items():
        if key in med:
            row = [what, secs(med[key]), f"{med[key] / sb3:.2f}x"]
            if sb3_defaults:
                row.append(f"{med[key] / sb3_defaults:.2f}x")
            rows.append([*row, bar])
    return rows


#: a level's label in the chunk table (the first result file called XLA's default "-O2"; it
#: is level 3)
_LEVEL = {"-O2": "default (3)", "default": "default (3)", "-O1": "1"}


def fair_peer_ratios(recs: list[Rec]) -> Cells:
    """:func:`main_command_ratios` against the fair peer's targets (cold <= 1.0x, warm <=
    0.5x)."""
    return main_command_ratios(recs, ("<= 1.0x", "<= 0.5x"))


def chunk_options(recs: list[Rec]) -> Cells:
    """Per task and engine, the chunk's compile and run at XLA's default backend level and
    at 1: each level's median over the rounds (and every round), over the default's."""
    head = ["task", "engine", "level", "compile", "s a chunk", "compile / default"]
    cells = [[*head, "chunk / default"]]
    for rec in recs:
        found: dict[tuple[str, str], dict[str, list[Row]]] = {}
        for r in rec["rows"]:
            level = _LEVEL[r["level"]]
            found.setdefault((r["env_id"], r["physics"]), {}).setdefault(level, []).append(r)
        for (task, physics), levels in found.items():
            med = {
                lv: (
                    statistics.median(r["compile_s"] for r in rs),
                    statistics.median(r["seconds_per_chunk"] for r in rs),
                )
                for lv, rs in levels.items()
            }
            base = med["default (3)"]
            for lv, rs in levels.items():
                each = ", ".join(f"{r['compile_s']:.2f}" for r in rs)
                runs = ", ".join(f"{r['seconds_per_chunk']:.3f}" for r in rs)
                cells.append(
                    [
                        task,
                        physics,
                        lv,
                        f"{med[lv][0]:.2f} s ({each})",
                        f"{med[lv][1]:.3f} s ({runs})",
                        f"{med[lv][0] / base[0]:.2f}x",
                        f"{med[lv][1] / base[1]:.2f}x",
                    ]
                )
    return cells


TABLES = {
    "main-command-cpu2": Table(("main_command_cpu2",), main_command),
    "main-command-ratios-cpu2": Table(("main_command_cpu2",), main_command_ratios),
    "main-command-ratios-pool-cpu2": Table(("main_command_cpu2_pool",), main_command_ratios),
    "main-command-ratios-video-cpu2": Table(("main_command_cpu2_video",), main_command_ratios),
    "main-command-ratios-emitters-cpu2": Table(
        ("main_command_cpu2_emitters",), main_command_ratios
    ),
    "main-command-ratios-sb3-defaults-cpu2": Table(
        ("main_command_cpu2_sb3_defaults",), main_command_ratios
    ),
    # against the fair peer, with the later targets
    "main-command-ratios-worker-cpu2": Table(
        ("main_command_cpu2_worker",),
        fair_peer_ratios,
    ),
    "main-command-ratios-evaluator-later-cpu2": Table(
        ("main_command_cpu2_evaluator_later",),
        fair_peer_ratios,
    ),
    "chunk-options-cpu2": Table(("chunk_options_cpu2",), chunk_options),
    "main-command-ratios-o1-chunk-cpu2": Table(
        ("main_command_cpu2_o1_chunk",),
        fair_peer_ratios,
    ),
    "main-command-ratios-init-once-cpu2": Table(
        ("main_command_cpu2_init_once",),
        fair_peer_ratios,
    ),
    "main-command-ratios-startup-cpu2": Table(("main_command_cpu2_startup",), fair_peer_ratios),
    "main-command-ratios-ultrafast-cpu2": Table(("main_command_cpu2_ultrafast",), fair_peer_ratios),
    "main-command-ratios-store-cpu2": Table(("main_command_cpu2_store",), fair_peer_ratios),
    "main-command-ratios-store-reviewed-cpu2": Table(
        ("main_command_cpu2_store_reviewed",), fair_peer_ratios
    ),
    "main-command-ratios-preload-cpu2": Table(("main_command_cpu2_preload",), fair_peer_ratios),
    "main-command-ratios-gc-cpu2": Table(("main_command_cpu2_gc",), fair_peer_ratios),
    "main-command-ratios-chunk-cpu2": Table(("main_command_cpu2_chunk",), fair_peer_ratios),
    "main-command-ratios-head-cpu2": Table(("main_command_cpu2_head",), fair_peer_ratios),
}
