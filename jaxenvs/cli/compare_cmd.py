"""``jaxenvs compare``: overlay the learning curves of several runs (e.g. Q-learning vs SARSA)."""

from __future__ import annotations

import argparse
import json
from pathlib import Path

HELP = "overlay the learning curves of run directories in one plot"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("run_dirs", metavar="DIR", nargs="+", help="run directories")
    parser.add_argument("--out", metavar="PLOT.png", default="compare.png", help="output image")
    parser.add_argument("--labels", nargs="+", help="one legend label per run")


def run(args: argparse.Namespace) -> int:
    from jaxenvs.run import results, run_config

    dirs = [Path(d) for d in args.run_dirs]
    for d in dirs:
        if not (d / run_config.PROGRESS_FILE).is_file():
            raise ValueError(f"{d} is not a run directory (no {run_config.PROGRESS_FILE})")
    if args.labels and len(args.labels) != len(dirs):
        raise ValueError(f"--labels needs {len(dirs)} labels, got {len(args.labels)}")
    out = results.plot_curves(dirs, args.out, args.labels)
    print(f"{'run':40s} {'eval return':>14s} {'steps':>10s} {'overall':>8s} {'best100':>8s}")
    for d in dirs:
        try:
            s = json.loads((d / run_config.SUMMARY_FILE).read_text())
        except (OSError, ValueError):
            print(f"{str(d):40s} (no summary yet)")
            continue
        b100 = s.get("best_100_score")
        print(
            f"{str(d):40s} {s['eval_mean_return']:8.1f}+-{s['eval_std_return']:<5.1f} "
            f"{s['env_steps']:>10d} {s['overall_score']:8.1f} "
            f"{'-' if b100 is None else f'{b100:.1f}':>8s}"
        )
    print(f"plot: {out}")
    return 0
