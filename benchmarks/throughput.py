"""Env steps per second of the batched, auto-resetting env with random actions.

Each measurement jits ``lax.scan`` over ``steps`` batched steps (observation, reward and
auto-reset included), times the first call (compile + run) and then the median of
``repeats`` further calls, and reads the process's peak resident memory.

    python benchmarks/throughput.py --tasks CartPole-v0 --batches 256 4096 16384 \
        --json benchmarks/throughput.json
"""

from __future__ import annotations

import argparse
import json
import platform
import resource
import statistics
import time
from typing import Any

import jax

import jaxenvs
from jaxenvs.testing import random_actions


def measure(env_id: str, num_envs: int, steps: int = 100, repeats: int = 5) -> dict[str, Any]:
    """Throughput of ``env_id`` at batch ``num_envs``: a dict of figures."""
    benv = jaxenvs.make(env_id, num_envs=num_envs)

    def run(key: jax.Array) -> jax.Array:
        reset_key, run_key = jax.random.split(key)
        state = benv.reset(reset_key)

        def body(state, k):  # type: ignore[no-untyped-def]
            state = benv.step(state, random_actions(benv.env, k, (num_envs,)))
            return state, None

        state, _ = jax.lax.scan(body, state, jax.random.split(run_key, steps))
        return state.reward.sum()

    fn = jax.jit(run)
    t0 = time.perf_counter()
    jax.block_until_ready(fn(jax.random.key(0)))
    first_call = time.perf_counter() - t0
    times = []
    for i in range(repeats):
        t0 = time.perf_counter()
        jax.block_until_ready(fn(jax.random.key(i + 1)))
        times.append(time.perf_counter() - t0)
    wall = statistics.median(times)
    return {
        "task": env_id,
        "num_envs": num_envs,
        "steps_per_call": steps,
        "env_steps_per_s": num_envs * steps / wall,
        "physics_steps_per_s": num_envs * steps * benv.env.sim.substeps / wall,
        "first_call_s": first_call,
        "median_call_s": wall,
        "peak_rss_mib": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024,
    }


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--tasks", nargs="+", default=["CartPole-v0"])
    parser.add_argument("--batches", nargs="+", type=int, default=[256, 4096, 16384])
    parser.add_argument("--steps", type=int, default=100)
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--json", default=None, help="write the results here")
    args = parser.parse_args(argv)
    machine = (
        f"{platform.node()} {platform.machine()} jax {jax.__version__} "
        f"{jax.devices()[0].device_kind}"
    )
    print(f"# {machine}")
    print(f"{'task':20s} {'envs':>7s} {'env steps/s':>14s} {'first call s':>13s} {'peak MiB':>9s}")
    results = []
    for env_id in args.tasks:
        for b in args.batches:
            r = measure(env_id, b, args.steps, args.repeats)
            results.append(r)
            print(
                f"{env_id:20s} {b:7d} {r['env_steps_per_s']:14,.0f} "
                f"{r['first_call_s']:13.1f} {r['peak_rss_mib']:9.0f}",
                flush=True,
            )
    if args.json:
        with open(args.json, "w") as f:
            json.dump({"machine": machine, "results": results}, f, indent=2)


if __name__ == "__main__":
    main()
