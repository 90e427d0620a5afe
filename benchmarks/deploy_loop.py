"""The real-time deploy loop on a trained, exported policy through the simulated robot.

Trains the task with PPO (``jaxenvs train ID --algo ppo``, the shipped config) unless
``--run`` names a run, exports it (``jaxenvs export --format onnx``), then runs
``jaxenvs deploy POLICY --env ID --robot sim --seconds S`` ``--repeats`` times at normal
priority and ``--repeats`` times with ``--realtime`` (SCHED_FIFO), interleaved. One row per
deploy run (its JSON summary), and one median row per priority. A row passes when the
task did not terminate, ``deadline_misses`` <= 1 % of the steps and the p99 period is
within 20 % of the control period.

    python benchmarks/deploy_loop.py --env CartPole-v0 --json deploy_cpu2_cartpole
    python benchmarks/deploy_loop.py --env Reacher-v0 --json deploy_cpu2_reacher
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path
from typing import Any

import numpy as np
import results_io

ROOT = Path(__file__).resolve().parents[1]
NUMBERS = (
    "steps",
    "return",
    "period_ms_mean",
    "period_ms_p99",
    "period_ms_max",
    "deadline_misses",
    "late_ms_p50",
    "late_ms_p99",
    "sensor_age_ms_mean",
    "round_trip_ms_p50",
    "round_trip_ms_p99",
)


def _jaxenvs(*args: str) -> str:
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    done = subprocess.run(
        [sys.executable, "-m", "jaxenvs", *args], capture_output=True, text=True, env=env
    )
    if done.returncode != 0:
        raise SystemExit(f"jaxenvs {args[0]} failed: {done.stderr.strip()[-500:]}")
    return done.stdout


def passes(s: dict[str, Any]) -> bool:
    """No termination, deadline misses <= 1 % of steps, p99 period within 20 %."""
    return (
        s["error"] is None
        and not s["terminated"]
        and s["deadline_misses"] <= 0.01 * s["steps"]
        and s["period_ms_p99"] <= 1.2 * s["target_period_ms"]
    )


def deploy(policy: Path, env_id: str, seconds: float, realtime: bool, work: Path) -> dict:
    """One ``jaxenvs deploy --robot sim`` run's summary, with its priority and verdict."""
    summary = work / "summary.json"
    flags = ["--realtime"] if realtime else []
    _jaxenvs(
        "deploy",
        str(policy),
        "--env",
        env_id,
        "--robot",
        "sim",
        "--seconds",
        str(seconds),
        "--summary",
        str(summary),
        *flags,
    )
    s = json.loads(summary.read_text())
    row = {"env_id": env_id, "priority": "SCHED_FIFO" if realtime else "normal"}
    row.update({k: s[k] for k in ("seconds", "terminated", "target_period_ms", *NUMBERS)})
    row["bad_messages"] = sum(s["bad_messages"].values()) + sum(s["robot_bad_messages"].values())
    row["passes"] = passes(s)
    print(json.dumps(row), flush=True)
    return row


def median_row(rows: list[dict[str, Any]]) -> dict[str, Any]:
    """The median of each number over ``rows`` (one priority), and whether all passed."""
    out = {"env_id": rows[0]["env_id"], "priority": rows[0]["priority"], "median_of": len(rows)}
    for k in NUMBERS:
        out[k] = float(np.median([r[k] for r in rows]))
    out["target_period_ms"] = rows[0]["target_period_ms"]
    out["terminated_runs"] = sum(r["terminated"] for r in rows)
    out["all_pass"] = all(r["passes"] for r in rows)
    return out


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--env", default="CartPole-v0")
    p.add_argument("--run", help="a trained PPO run directory (default: train one here)")
    p.add_argument("--seconds", type=float, default=60.0)
    p.add_argument("--repeats", type=int, default=3)
    p.add_argument("--json", help=results_io.HELP)
    args = p.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        work = Path(tmp)
        run = Path(args.run) if args.run else work / "run"
        if not args.run:
            print(_jaxenvs("train", args.env, "--algo", "ppo", "--out", str(run), "--quiet"))
        policy = work / "policy.onnx"
        print(_jaxenvs("export", str(run), "--format", "onnx", "--out", str(policy)).strip())
        rows = [
            deploy(policy, args.env, args.seconds, realtime, work)
            for _ in range(args.repeats)
            for realtime in (False, True)
        ]
    medians = [
        median_row([r for r in rows if r["priority"] == q]) for q in ("normal", "SCHED_FIFO")
    ]
    for m in medians:
        print(json.dumps(m))
    if args.json:
        rec = results_io.record(
            args.json,
            f"{args.env}: jaxenvs deploy through the simulated robot, {args.seconds:g} s, 2 cores",
            rows + medians,
            description="the shared 2-core development machine (other users' jobs running)",
            engine="c",
            notes=(
                "a trained PPO policy exported to ONNX, run by jaxenvs deploy --robot sim; the "
                "simulated robot and the loop share the 2 cores with other users' work. "
                "Rows alternate normal priority and --realtime (SCHED_FIFO); the last two rows "
                "are the medians of each. Pass: no termination, deadline misses <= 1 % of steps, "
                "p99 period within 20 % of the control period."
            ),
        )
        results_io.write(args.json, rec)


if __name__ == "__main__":
    main()
