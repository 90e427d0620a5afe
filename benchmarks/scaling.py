"""Scale-out: env steps/s and PPO wall time on 1 vs N devices (jaxenvs.core.sharding).

For each task and each device count, all in one process:

* **env steps/s**: ``steps`` auto-resetting batched steps with random actions per call,
  the env batch split over the devices and carried (donated) from call to call; the
  median of ``repeats`` timed calls after a compile-and-warm-up call. Two batch sizes per
  device count: the total ``--envs`` (strong scaling: the same work on more devices) and
  ``--envs`` per device (weak scaling).
* **PPO wall time**: ``--ppo-updates`` PPO updates (one chunk) with ``--ppo-envs`` envs in
  total, env states split over the devices and network parameters replicated; median of
  ``repeats`` timed chunks after the compile, plus the compile time.

    python benchmarks/scaling.py --tasks Reacher-v0 HexapodWalk-v0 --devices 1 2 \\
        --json scaling_h200x2_reacher_walker

On a CPU, add ``XLA_FLAGS=--xla_force_host_platform_device_count=2`` to try the code path
(the "devices" then share the same cores, so expect no speed-up).
"""

from __future__ import annotations

import argparse
import dataclasses
import platform
import statistics
import time
from typing import Any

import jax
import results_io

import jaxenvs
from jaxenvs.agents import ppo
from jaxenvs.core import BatchedEnv, Env, sharding
from jaxenvs.run.placement import shard_trainer_fns


def env_throughput(
    env_id: str, num_envs: int, devices: int, steps: int, repeats: int
) -> dict[str, Any]:
    """Env steps/s of ``num_envs`` envs split over the first ``devices`` devices."""
    benv = jaxenvs.make(env_id, num_envs=num_envs)
    assert isinstance(benv, BatchedEnv)
    mesh = sharding.make_mesh(devices)
    reset, run = sharding.make_sharded_steps(benv, mesh, steps)
    keys = iter(jax.random.split(jax.random.key(0), repeats + 2))
    t0 = time.perf_counter()
    state = jax.block_until_ready(run(reset(next(keys)), next(keys)))
    first = time.perf_counter() - t0
    times = []
    for k in keys:
        t0 = time.perf_counter()
        state = jax.block_until_ready(run(state, k))
        times.append(time.perf_counter() - t0)
    wall = statistics.median(times)
    return {
        "kind": "env",
        "task": env_id,
        "devices": devices,
        "num_envs": num_envs,
        "steps_per_call": steps,
        "env_steps_per_s": num_envs * steps / wall,
        "median_call_s": wall,
        "first_call_s": first,
    }


def ppo_wall_time(
    env_id: str, num_envs: int, devices: int, updates: int, repeats: int
) -> dict[str, Any]:
    """Seconds per ``updates`` PPO updates with ``num_envs`` envs over ``devices``."""
    env = jaxenvs.make(env_id)
    assert isinstance(env, Env)
    config = dataclasses.replace(
        ppo.PPOConfig(),
        num_envs=num_envs,
        num_steps=16,
        updates_per_chunk=updates,
        update_epochs=4,
        num_minibatches=4,
        total_steps=num_envs * 16 * updates * (repeats + 1),
    )
    trainer = ppo.make_trainer(env, config)
    mesh = sharding.make_mesh(devices)
    init, chunk = shard_trainer_fns(trainer, mesh, num_envs)
    t0 = time.perf_counter()
    state = jax.block_until_ready(init(jax.random.key(0)))
    state, metrics = jax.block_until_ready(chunk(state))
    first = time.perf_counter() - t0
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        state, metrics = jax.block_until_ready(chunk(state))
        times.append(time.perf_counter() - t0)
    wall = statistics.median(times)
    return {
        "kind": "ppo",
        "task": env_id,
        "devices": devices,
        "num_envs": num_envs,
        "updates_per_call": updates,
        "env_steps_per_call": config.steps_per_chunk,
        "median_call_s": wall,
        "env_steps_per_s": config.steps_per_chunk / wall,
        "first_call_s": first,
        "loss": float(metrics["loss"]),
    }


def _speedups(results: list[dict[str, Any]]) -> None:
    """Add ``speedup`` (steps/s over the 1-device figure of the same kind, task, batch
    scheme) to each result in place."""
    base: dict[tuple[Any, ...], float] = {}
    for r in results:
        if r["devices"] == 1:
            base[(r["kind"], r["task"], r.get("scheme"))] = r["env_steps_per_s"]
    for r in results:
        b = base.get((r["kind"], r["task"], r.get("scheme")))
        r["speedup"] = None if b is None else r["env_steps_per_s"] / b


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--tasks", nargs="+", default=["Reacher-v0", "HexapodWalk-v0"])
    parser.add_argument("--devices", nargs="+", type=int, default=[1, jax.device_count()])
    parser.add_argument("--envs", type=int, default=8192, help="total envs (strong scaling)")
    parser.add_argument("--steps", type=int, default=100, help="env steps per timed call")
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--ppo-envs", type=int, default=4096)
    parser.add_argument("--ppo-updates", type=int, default=4)
    parser.add_argument("--skip-ppo", action="store_true")
    parser.add_argument("--skip-env", action="store_true")
    parser.add_argument("--json", default=None, help=results_io.HELP)
    args = parser.parse_args(argv)
    devices = sorted(set(args.devices))
    for n in devices:
        sharding.validate_batch(args.envs, n)
        sharding.validate_batch(args.ppo_envs, n)
    dev = jax.devices()[0]
    machine = f"{platform.node()} jax {jax.__version__} {jax.device_count()} x {dev.device_kind}"
    print(f"# {machine}", flush=True)
    results: list[dict[str, Any]] = []

    def save() -> None:
        if args.json:
            title = f"{', '.join(args.tasks)} on {devices} devices: env steps/s and PPO"
            rec = results_io.record(args.json, title, results, extra={"args": vars(args)})
            results_io.write(args.json, rec)

    def report(r: dict[str, Any]) -> None:
        results.append(r)
        print(
            f"{r['kind']:4s} {r['task']:16s} {r.get('scheme', '-'):6s} devices {r['devices']} "
            f"envs {r['num_envs']:6d}  {r['env_steps_per_s']:14,.0f} env steps/s  "
            f"call {r['median_call_s']:.4f} s  first {r['first_call_s']:.1f} s",
            flush=True,
        )
        save()  # a run cut short still leaves what it measured

    # env throughput of every task first, then PPO: the cheaper figures come first
    if not args.skip_env:
        for task in args.tasks:
            for n in devices:
                r = env_throughput(task, args.envs, n, args.steps, args.repeats)
                report({**r, "scheme": "strong"})
                if n > 1:
                    r = env_throughput(task, args.envs * n, n, args.steps, args.repeats)
                    report({**r, "scheme": "weak"})
    if not args.skip_ppo:
        for task in args.tasks:
            for n in devices:
                report(ppo_wall_time(task, args.ppo_envs, n, args.ppo_updates, args.repeats))
    # weak scaling compares N devices at N x envs with one device at 1 x envs
    base_weak = {
        r["task"]: r["env_steps_per_s"] for r in results if r["kind"] == "env" and r["devices"] == 1
    }
    _speedups(results)
    for r in results:
        if r.get("scheme") == "weak":
            r["speedup"] = r["env_steps_per_s"] / base_weak[r["task"]]
    print("\nspeedup over 1 device:")
    for r in results:
        if r["devices"] > 1 and r.get("speedup") is not None:
            print(
                f"  {r['kind']:4s} {r['task']:16s} {r.get('scheme', 'strong'):6s} "
                f"{r['devices']} devices: {r['speedup']:.2f}x"
            )
    save()


if __name__ == "__main__":
    main()
