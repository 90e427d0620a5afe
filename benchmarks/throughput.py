"""Env steps per second of our batched envs with random actions (no peers).

A thin script over :mod:`jaxenvs.bench` (the library behind ``jaxenvs bench``): each
measurement jits ``lax.scan`` over ``steps`` batched steps, times the first call
(trace + compile + run) and the median of ``repeats`` further calls.

    python benchmarks/throughput.py --tasks CartPole-v0 --batches 256 4096 16384 \\
        --modes full functional --json throughput_cpu2_cartpole
"""

from __future__ import annotations

import argparse

import results_io

from jaxenvs.bench import MODES, format_table, machine, measure


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=(__doc__ or "").splitlines()[0])
    parser.add_argument("--tasks", nargs="+", default=["CartPole-v0"])
    parser.add_argument("--batches", nargs="+", type=int, default=[256, 4096, 16384])
    parser.add_argument("--modes", nargs="+", default=["full"], choices=MODES)
    parser.add_argument("--steps", type=int, default=100)
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--json", default=None, help=results_io.HELP)
    args = parser.parse_args(argv)
    info = machine()
    print(f"# {info['host']} {info['device']} jax {info['jax']}")
    rows: list[list[object]] = [["task", "mode", "envs", "env steps/s", "first call s", "MiB"]]
    results = []
    for env_id in args.tasks:
        for b in args.batches:
            for mode in args.modes:
                r = measure(env_id, b, args.steps, args.repeats, mode)
                results.append(r)
                rows.append(
                    [
                        env_id,
                        mode,
                        b,
                        f"{r['env_steps_per_s']:,.0f}",
                        f"{r['first_call_s']:.1f}",
                        f"{r['peak_rss_mib']:.0f}",
                    ]
                )
                print(" ".join(str(c) for c in rows[-1]), flush=True)
    print(format_table(rows))
    if args.json:
        title = f"env steps/s of {', '.join(args.tasks)} ({', '.join(args.modes)})"
        results_io.write(args.json, results_io.record(args.json, title, results, extra=info))


if __name__ == "__main__":
    main()
