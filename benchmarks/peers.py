"""Ours beside the peers, in one run, and the CPU targets of the throughput issue.

For every task that has peers (CartPole-v0, Reacher-v0, HexapodWalk-v0 where registered):
our batched env over a batch sweep, then Gymnasium (one env, SyncVectorEnv), EnvPool
(all cores), MuJoCo's C rollout on our own MJCF at our substeps (all cores) and gymnax's
closed-form CartPole, all timed in the same interleaved rounds (medians). Peers that are
not installed are listed as skipped. Ends with the targets, met or missed.

    python benchmarks/peers.py --batches 256 2048 16384 --json peers_cpu2_cartpole_reacher
"""

from __future__ import annotations

import argparse
from typing import Any

import results_io

import jaxenvs
from jaxenvs import bench
from jaxenvs.bench.peers import peer_runners

#: CPU targets: task -> (peer name, peer variant, minimum ratio ours / peer).
TARGETS = (
    ("CartPole-v0", "envpool", "CartPole-v1", 2.5),
    ("Reacher-v0", "envpool", "Reacher-v4", 10.0),
    ("HexapodWalk-v0", "envpool", "Ant-v4", 2.0),
)
FIRST_CALL_S = 20.0


def verdicts(results: list[dict[str, Any]]) -> list[list[Any]]:
    """One row per target: the measured figure, the bar, met or missed."""
    rows: list[list[Any]] = [["task", "target", "measured", "verdict"]]
    for task, name, variant, bar in TARGETS:
        best = bench.best_of(results, task)
        peer = next(
            (
                r
                for r in results
                if r["task"] == task and r["name"] == name and not r.get("skipped")
            ),
            None,
        )
        if best is None or peer is None:
            rows.append([task, f">= {bar}x {name} {variant}", "not measured", "-"])
            continue
        ratio = best["env_steps_per_s"] / peer["env_steps_per_s"]
        rows.append([task, f">= {bar}x {name} {variant}", f"{ratio:.2f}x", _verdict(ratio >= bar)])
    for task in sorted({r["task"] for r in results if r["name"] == "jaxenvs"}):
        ours = [r for r in results if r["task"] == task and r["name"] == "jaxenvs"]
        first = max(r["first_call_s"] for r in ours)
        rows.append(
            [
                task,
                f"first call <= {FIRST_CALL_S:.0f} s",
                f"{first:.1f} s (worst)",
                _verdict(first <= FIRST_CALL_S),
            ]
        )
        rollout = next(
            (
                r
                for r in results
                if r["task"] == task and r["name"] == "mujoco.rollout" and not r.get("skipped")
            ),
            None,
        )
        best = bench.best_of(results, task)
        if rollout is not None and best is not None:
            ratio = best["env_steps_per_s"] / rollout["env_steps_per_s"]
            rows.append([task, ">= 1x mujoco.rollout", f"{ratio:.2f}x", _verdict(ratio >= 1.0)])
    return rows


def _verdict(ok: bool) -> str:
    return "met" if ok else "MISSED"


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=(__doc__ or "").splitlines()[0])
    parser.add_argument("--tasks", nargs="+", default=None)
    parser.add_argument("--batches", nargs="+", type=int, default=[256, 2048, 16384])
    parser.add_argument("--steps", type=int, default=100)
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--peer-envs", type=int, default=256)
    parser.add_argument("--json", default=None, help=results_io.HELP)
    args = parser.parse_args(argv)
    ids = jaxenvs.list_envs()
    tasks = args.tasks or [t for t, *_ in TARGETS if t in ids]
    runners: list[bench.Runner] = []
    skipped = []
    for task in tasks:
        for b in args.batches:
            print(f"# compiling {task} x{b}", flush=True)
            runners.append(bench.prepare_ours(task, b, "full", args.steps))
        for p in peer_runners(task, args.peer_envs, max(args.batches)):
            if isinstance(p, bench.Runner):
                runners.append(p)
            else:
                skipped.append(p.as_dict())
    results = bench.time_runners(runners, args.repeats, log=lambda m: print(f"# {m}"))
    results += skipped
    rows: list[list[Any]] = [["task", "who", "variant", "envs", "env steps/s"]]
    for r in results:
        sps = "skipped: " + r["reason"] if r.get("skipped") else f"{r['env_steps_per_s']:,.0f}"
        rows.append([r["task"], r["name"], r["variant"], r.get("num_envs", "-"), sps])
    print(bench.format_table(rows))
    print()
    table = verdicts(results)
    print(bench.format_table(table))
    if args.json:
        title = f"{', '.join(tasks)} beside the peers"
        extra = {"bench_machine": bench.machine(), "targets": table}
        results_io.write(args.json, results_io.record(args.json, title, results, extra=extra))


if __name__ == "__main__":
    main()
