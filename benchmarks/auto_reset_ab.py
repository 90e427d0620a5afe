"""The compact auto-reset against resetting the whole batch, side by side in one process.

Each plan entry ``[task, steps, [batches], [variants]]`` prepares ``jaxenvs bench``'s full
step (:func:`jaxenvs.bench.prepare_ours`) once per batch and variant, and MuJoCo's
``rollout`` on the task's MJCF at 4,096 envs beside them; all are timed in the same
interleaved rounds (:func:`jaxenvs.bench.time_runners`, 3 rounds of ~0.3 s, medians).
A variant is ``compact`` (the library's step) or ``whole`` (the same step with
``jaxenvs.core.batch.reset_slots`` returning 0: fresh starts for the whole batch whenever
an env finished), optionally with ``_mjx`` (default engine: C). The host devices are
JAX's (set ``XLA_FLAGS=--xla_force_host_platform_device_count=N``; one without it).

    XLA_FLAGS=--xla_force_host_platform_device_count=8 JAX_PLATFORMS=cpu \\
      python benchmarks/auto_reset_ab.py \\
      '[["CartPole-v0", 50, [4096, 16384], ["compact", "whole"]]]' --json NAME
"""

from __future__ import annotations

import argparse
import json
import time

import results_io

from jaxenvs import bench
from jaxenvs.bench import peers
from jaxenvs.core import batch


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("plan", help="JSON: [[task, steps, [batches], [variants]], ...]")
    parser.add_argument("--json", help=results_io.HELP)
    parser.add_argument("--description", default="", help="the machine, in words")
    args = parser.parse_args()
    compact = batch.reset_slots
    runners = []
    for task, steps, batches, variants in json.loads(args.plan):
        for n in batches:
            for variant in variants:
                kind, _, physics = variant.partition("_")
                if kind not in ("compact", "whole"):
                    raise SystemExit(f"unknown variant {variant!r}: compact or whole[_mjx]")
                batch.reset_slots = compact if kind == "compact" else (lambda n, p="cpu": 0)
                t0 = time.perf_counter()
                runner = bench.prepare_ours(task, n, "full", steps, physics=physics or "c")
                runner.variant = variant
                print(f"# prepared {task} x{n} {variant} in {time.perf_counter() - t0:.1f} s")
                runners.append(runner)
        rollout = peers.peer_runners(task, 4096, names=("mujoco.rollout",))
        runners += [p for p in rollout if isinstance(p, bench.Runner)]
    batch.reset_slots = compact
    results = bench.time_runners(runners, repeats=3, target_s=0.3)
    for r in results:
        print(
            f"{r['task']:16s} {r['name']:16s} {r['variant']:12s} {r['num_envs']:>6,d} "
            f"{r['env_steps_per_s']:>12,.0f} devices={r.get('devices')}"
        )
    if args.json:
        results_io.write_plan_run(
            args.json,
            "The compact auto-reset against resetting the whole batch, one process",
            "auto_reset_ab.py",
            args.plan,
            results,
            args.description,
            extra={"machine": bench.machine()},
        )


if __name__ == "__main__":
    main()
