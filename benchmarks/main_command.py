"""Whole-command times of the README's main job, cold (a fresh compile cache) and warm.

Runs ``jaxenvs train CartPole-v0 --algo ppo`` (video included, as the README runs it)
``--runs`` times in a row against one fresh cache directory: the first run is cold, the
others load what it stored. Then the same with ``--physics c --no-video``, whose second run
should take at most half the first's time. Each row: the command, the run's index, its
wall time from process start to exit, the training wall the run reports, its engine and
eval return.

    python benchmarks/main_command.py --json main_command_cpu2
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import results_io

COMMANDS = (
    ("main", ["train", "CartPole-v0", "--algo", "ppo"]),
    ("c_no_video", ["train", "CartPole-v0", "--algo", "ppo", "--physics", "c", "--no-video"]),
)


def _run(args: list[str], out: Path, cache: str) -> dict:
    env = {**os.environ, "JAXENVS_CACHE_DIR": cache}
    start = time.perf_counter()
    subprocess.run(
        [sys.executable, "-m", "jaxenvs", *args, "--out", str(out), "--quiet"],
        check=True,
        env=env,
        timeout=900,
    )
    wall = time.perf_counter() - start
    summary = json.loads((out / "summary.json").read_text())
    return {
        "whole_command_s": round(wall, 2),
        "train_wall_s": summary.get("wall_seconds"),
        "physics": summary.get("physics"),
        "eval_mean_return": summary.get("eval_mean_return"),
        "video": (out / "video.mp4").exists(),
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--runs", type=int, default=2)
    parser.add_argument("--json", help=results_io.HELP)
    args = parser.parse_args()
    rows = []
    for name, command in COMMANDS:
        with tempfile.TemporaryDirectory() as tmp:
            cache = str(Path(tmp) / "cache")
            for i in range(args.runs):
                row = _run(command, Path(tmp) / f"run{i}", cache)
                row = {"command": "jaxenvs " + " ".join(command), "which": name, "run": i, **row}
                rows.append(row)
                print(row, flush=True)
    if args.json:
        title = "The README's main command and a C-engine PPO run, cold then warm"
        results_io.write(args.json, results_io.record(args.json, title, rows))


if __name__ == "__main__":
    main()
