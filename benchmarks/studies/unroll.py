"""Side-by-side timing of one task's rollout loop at several ``lax.scan`` unroll factors.

Each variant is the full auto-resetting batched step with uniform random actions, a
``lax.scan`` of ``--steps`` steps jitted with the state donated. All variants are compiled
first, then timed in turn, round after round (median over rounds), so they share whatever
the machine is doing. This is the measurement behind each task's ``scan_unroll``.

    python benchmarks/studies/unroll.py --task CartPole-v0 --batch 16384 --unrolls 1 4 5 8
"""

from __future__ import annotations

import argparse
import statistics
import time
from typing import Any

import jax

import jaxenvs
from jaxenvs.actions import random_actions
from jaxenvs.core import BatchedEnv, State


def make_run(benv: BatchedEnv, steps: int, unroll: int) -> Any:
    """``run(state, key) -> state``: ``steps`` batched steps, scan unrolled ``unroll`` times."""

    def body(s: State, k: jax.Array) -> tuple[State, None]:
        return benv.step(s, random_actions(benv.env, k, (benv.num_envs,))), None

    def run(state: State, key: jax.Array) -> State:
        keys = jax.random.split(key, steps)
        return jax.lax.scan(body, state, keys, unroll=unroll)[0]

    return jax.jit(run, donate_argnums=0)


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=(__doc__ or "").splitlines()[0])
    parser.add_argument("--task", default="CartPole-v0")
    parser.add_argument("--batch", type=int, default=16384)
    parser.add_argument("--unrolls", nargs="+", type=int, default=[1, 2, 4, 5, 8])
    parser.add_argument("--steps", type=int, default=100)
    parser.add_argument("--rounds", type=int, default=7)
    args = parser.parse_args(argv)
    benv = jaxenvs.make(args.task, num_envs=args.batch)
    assert isinstance(benv, BatchedEnv)
    variants: dict[int, dict[str, Any]] = {}
    for u in args.unrolls:
        run = make_run(benv, args.steps, u)
        state = jax.jit(benv.reset)(jax.random.key(0))
        t0 = time.perf_counter()
        state = jax.block_until_ready(run(state, jax.random.key(1)))
        variants[u] = {"run": run, "state": state, "first": time.perf_counter() - t0, "rates": []}
    key = jax.random.key(2)
    for _ in range(args.rounds):
        for v in variants.values():
            key, k = jax.random.split(key)
            t0 = time.perf_counter()
            v["state"] = jax.block_until_ready(v["run"](v["state"], k))
            v["rates"].append(args.batch * args.steps / (time.perf_counter() - t0))
    print(f"# {args.task}, {args.batch} envs, jax {jax.__version__} on {jax.devices()[0]}")
    print("unroll  env steps/s  first call s")
    for u, v in variants.items():
        print(f"{u:6d}  {statistics.median(v['rates']):11,.0f}  {v['first']:12.1f}")


if __name__ == "__main__":
    main()
