"""A joystick policy driven through the simulated robot's link, by a script.

Exports a trained run (``jaxenvs export RUN --format onnx``) and runs ``jaxenvs deploy
POLICY --env HexapodJoystick-v0 --robot sim --seconds 60 --command SCRIPT`` with the link's
``--latency-ms``, ``--jitter-ms`` and ``--noise`` of each ``--link`` (``--env
HexapodJoystickRough-v0 --terrain LEVEL[:TYPE]``: the rough policy, the simulated robot on a
tile of that level) (the first
``--repeats`` times, the others once; by default 30 +- 10 ms with noise 1, then the ideal
link: no delay, no noise, the reference of the same script). :data:`SCRIPT`: forward,
turning on the spot, sideways, standing, 15 s each. The tracking errors are the loop
summary's ``tracking_error_rms``: the RMS over the run's control steps of |command -
velocity| (horizontal, m/s; and yaw rate, rad/s), the velocity from the simulated robot's
ground truth (body-frame mean velocity over each control period, as the task's
``lin_error`` and ``yaw_error``), the command the one in force at the loop.

A run passes when the robot did not fall (the task's termination) and both errors are
within :data:`TOLERANCE` times the policy's figures in simulation (``--reference
NAME:SEED:BENCH``: a result file's row of the exported seed, e.g.
``ppo_joystick_seeds_h200:0:mujoco_c``, or ``...:mujoco_c.mid`` for a group within it;
by default seed 0 of ``ppo_joystick_seeds_gap_h100``, the link variant: 20 s episodes,
commands redrawn over the full range, the run's action delays and sensor biases drawn per
env). The exported
seed is the run's best (a one-seed run: its only one), so name that seed. One row
per run (with its link settings), and one median row per link setting. ``--gif`` draws
the first run from its log (``/robot/state``, every ``--every`` control steps).

    python benchmarks/deploy_joystick.py --run /tmp/runs/joy0 --json deploy_cpu2_joystick \\
        --gif benchmarks/images/hexapod_joystick_deploy.gif
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
ENV_ID = "HexapodJoystick-v0"
#: (start s, vx m/s, vy m/s, yaw rate rad/s): the command script
SCRIPT = (
    (0.0, 0.3, 0.0, 0.0),
    (15.0, 0.0, 0.0, 0.6),
    (30.0, 0.0, -0.2, 0.0),
    (45.0, 0.0, 0.0, 0.0),
)
#: the errors may be this many times the simulation's
TOLERANCE = 1.5
#: the result file, seed and bench whose simulation figures are the reference (default;
#: ``--reference NAME:SEED:BENCH`` names another, the run's own)
REFERENCE = ("ppo_joystick_seeds_gap_h100", 0, "mjx")
NUMBERS = (
    "steps",
    "lin_rms",
    "yaw_rms",
    "period_ms_mean",
    "period_ms_p99",
    "deadline_misses",
    "late_ms_p99",
    "round_trip_ms_p50",
)


def reference(ref: tuple[str, int, str] = REFERENCE) -> dict[str, float]:
    """The policy's tracking errors in simulation (``ref``: result file, seed, bench)."""
    name, seed, bench = ref
    rec = json.loads((results_io.RESULTS_DIR / f"{name}.json").read_text())
    row = next(r for r in rec["rows"] if r["seed"] == seed)
    for key in bench.split("."):  # a group within a bench: mujoco_c.mid
        row = row[key]
    return {"lin": row["tracking_error_lin"], "yaw": row["tracking_error_yaw"]}


def _jaxenvs(*args: str, failed_ok: bool = False) -> str:
    """``jaxenvs ARGS``' standard output (and its error line, when ``failed_ok`` and the
    command stopped on a failure with status 1)."""
    env = {**os.environ, "PYTHONPATH": str(ROOT), "MUJOCO_GL": "egl"}
    done = subprocess.run(
        [sys.executable, "-m", "jaxenvs", *args], capture_output=True, text=True, env=env
    )
    if done.returncode == 1 and failed_ok:
        return done.stdout + done.stderr
    if done.returncode != 0:
        raise SystemExit(f"jaxenvs {args[0]} failed: {done.stderr.strip()[-500:]}")
    return done.stdout


def deploy(
    policy: Path, script: Path, link: dict[str, float], args: Any, work: Path, log: Path | None
) -> dict[str, Any]:
    """One deploy run's row: its link settings, the summary's figures and the verdict."""
    summary = work / "summary.json"
    flags = [x for k, v in link.items() for x in (f"--{k.replace('_', '-')}", f"{v:g}")]
    if args.terrain:
        flags += ["--terrain", args.terrain]
    if log is not None:
        flags += ["--log", str(log)]
    out = _jaxenvs(
        "deploy",
        str(policy),
        "--env",
        args.env,
        "--robot",
        "sim",
        "--seconds",
        f"{args.seconds:g}",
        "--command",
        str(script),
        "--summary",
        str(summary),
        *flags,
        failed_ok=True,
    )
    print(out.strip().splitlines()[-1], flush=True)
    s = json.loads(summary.read_text())
    ref = reference(args.reference)
    row: dict[str, Any] = {"env_id": args.env, **link, "seconds": s["seconds"]}
    if args.terrain:
        row["terrain"] = args.terrain
    row.update({k: s[k] for k in NUMBERS if k in s})
    row["lin_rms"] = s["tracking_error_rms"]["lin"]  # over the steps before any error
    row["yaw_rms"] = s["tracking_error_rms"]["yaw"]
    row["fell"] = bool(s["terminated"])
    row["error"] = s["error"]
    row["passes"] = (
        s["error"] is None
        and not s["terminated"]
        and row["lin_rms"] <= TOLERANCE * ref["lin"]
        and row["yaw_rms"] <= TOLERANCE * ref["yaw"]
    )
    print(json.dumps(row), flush=True)
    return row


def median_row(rows: list[dict[str, Any]]) -> dict[str, Any]:
    """The median of each number over ``rows`` (one link setting), falls, all passed."""
    keys = ("latency_ms", "jitter_ms", "noise")
    out: dict[str, Any] = {"env_id": rows[0]["env_id"], **{k: rows[0][k] for k in keys}}
    out["median_of"] = len(rows)
    for k in NUMBERS:
        out[k] = float(np.median([r[k] for r in rows]))
    out["falls"] = sum(r["fell"] for r in rows)
    out["all_pass"] = all(r["passes"] for r in rows)
    return out


def draw(log: Path, gif: Path, every: int, env_id: str = ENV_ID) -> None:
    """A GIF of a deploy log's ground truth, every ``every`` control steps; the red marker
    sits where the command in force would take the body in 1.5 s."""
    from seeds import render_drive

    from jaxenvs.deploy.log import read_log

    states = read_log(log)["/robot/state"]
    qpos = np.asarray([m["qpos"] for m in states])
    starts = np.asarray([t for t, *_ in SCRIPT])
    values = np.asarray([v for _, *v in SCRIPT], np.float32)
    times = np.arange(len(qpos)) * 0.05
    command = values[np.searchsorted(starts, times, side="right") - 1]
    render_drive({"qpos": qpos, "command": command}, str(gif), every=every, env_id=env_id)


def _link(text: str) -> dict[str, float]:
    try:
        latency, jitter, noise = (float(x) for x in text.split(","))
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected L,J,N numbers, not {text!r}") from None
    return {"latency_ms": latency, "jitter_ms": jitter, "noise": noise}


def _reference(text: str) -> tuple[str, int, str]:
    try:
        name, seed, bench = text.split(":")
        return name, int(seed), bench
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected NAME:SEED:BENCH, not {text!r}") from None


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--run", required=True, help="a trained joystick run directory")
    p.add_argument("--env", default=ENV_ID, help="its task (default: %(default)s)")
    p.add_argument("--terrain", metavar="LEVEL[:TYPE]", help="a terrain task's tile (sim robot)")
    p.add_argument("--seconds", type=float, default=60.0)
    p.add_argument(
        "--link",
        type=_link,
        action="append",
        metavar="L,J,N",
        help="the link's latency (ms), jitter (ms) and noise; repeatable; the first is run "
        "--repeats times, the others once (default: 30,10,1 then the ideal link 0,0,0)",
    )
    p.add_argument("--repeats", type=int, default=3)
    p.add_argument("--gif", metavar="OUT.gif", help="draw the first run (MUJOCO_GL=egl)")
    p.add_argument("--every", type=int, default=8, help="the GIF's control steps per frame")
    p.add_argument(
        "--reference",
        type=_reference,
        default=REFERENCE,
        metavar="NAME:SEED:BENCH",
        help="the result file, seed and bench (mjx, mujoco_c, ...) of the run's simulation "
        "figures (default: %(default)s)",
    )
    p.add_argument("--json", help=results_io.HELP)
    args = p.parse_args()
    links = args.link or [_link("30,10,1"), _link("0,0,0")]
    with tempfile.TemporaryDirectory() as tmp:
        work = Path(tmp)
        script = work / "script.txt"
        script.write_text("".join(" ".join(f"{x:g}" for x in line) + "\n" for line in SCRIPT))
        policy = work / "policy.onnx"
        print(_jaxenvs("export", args.run, "--format", "onnx", "--out", str(policy)).strip())
        log = work / "run.mcap"
        runs = [links[0]] * args.repeats + links[1:]
        rows = [
            deploy(policy, script, link, args, work, log if k == 0 else None)
            for k, link in enumerate(runs)
        ]
        if args.gif:
            draw(log, Path(args.gif), args.every, args.env)
    medians = [
        median_row([r for r in rows if all(r[k] == v for k, v in ln.items())]) for ln in links
    ]
    for m in medians:
        print(json.dumps(m))
    if args.json:
        ref = reference(args.reference)
        rec = results_io.record(
            args.json,
            f"{args.env}: jaxenvs deploy through the simulated robot, a 60 s command script, "
            "2 cores",
            rows + medians,
            description="the shared 2-core development machine (other users' jobs running)",
            engine="c",
            notes=(
                "the run's policy exported to ONNX, run by jaxenvs deploy --robot sim --command "
                f"(script: {list(SCRIPT)}, start s, vx, vy, yaw rate); tracking errors from "
                "the simulated robot's ground truth against the command in force. Pass: no "
                f"fall, both errors <= {TOLERANCE} x the simulation's (lin {ref['lin']}, yaw "
                f"{ref['yaw']}: {args.reference[0]} seed {args.reference[1]}, "
                f"{args.reference[2]}). The last rows are the medians of "
                "each link setting; the first link ran --repeats times, the others once; "
                "the ideal link (no delay, no noise) is the reference of the same script."
            ),
        )
        results_io.write(args.json, rec)


if __name__ == "__main__":
    main()
