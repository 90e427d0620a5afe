"""Soak test (not in CI): many env steps per task under random and extreme actions.

Every task runs a batch of auto-resetting envs for ``--steps`` env steps (or until
``--seconds`` after the first, compiling, block run out, whichever comes first) in
compiled blocks of ``--block`` steps.
Each step, every env draws its action from one of:

* a uniform random action of the space (half of the envs on average);
* an extreme one: NaN, +inf, -inf, +1e9 or -1e9 in every entry (continuous tasks), or
  an integer anywhere in int32 (discrete tasks; out of range gets clipped).

After every block the host checks that no non-finite value reached ``obs``, ``reward``
or ``info["final_obs"]``, and records the diverged-env count, the NaN-action count,
finished episodes and the process RSS. The RSS series (after the first block, which
holds the compile) shows whether memory stays flat. Exit status 1 if any non-finite
value reached an observation or a reward.

    python benchmarks/soak.py --steps 1e8 --seconds 600 --out soak.json
    python benchmarks/soak.py --tasks CartPole-v0 Reacher-v0 --num-envs 256
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
import results_io

import jaxenvs
from jaxenvs.core import BatchedEnv

EXTREMES = jnp.array([jnp.nan, jnp.inf, -jnp.inf, 1e9, -1e9], jnp.float32)


def rss_mb() -> float:
    """Resident set size of this process in MiB (Linux /proc; ru_maxrss elsewhere)."""
    try:
        for line in Path("/proc/self/status").read_text().splitlines():
            if line.startswith("VmRSS:"):
                return int(line.split()[1]) / 1024.0
    except OSError:
        pass
    import resource

    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


def soak_actions(benv: BatchedEnv, key: jax.Array) -> jax.Array:
    """One batch of actions: per env, random in the space or extreme (see module doc)."""
    env = benv.env
    n = benv.num_envs
    pick_key, rand_key, ext_key = jax.random.split(key, 3)
    extreme = jax.random.bernoulli(pick_key, 0.5, (n,))
    if env.discrete:
        fine = jax.random.randint(rand_key, (n,), 0, env.action_size)
        wild = jax.random.randint(ext_key, (n,), jnp.iinfo(jnp.int32).min, jnp.iinfo(jnp.int32).max)
        return jnp.where(extreme, wild, fine).astype(jnp.int32)
    shape = (n, env.action_size)
    fine = jax.random.uniform(rand_key, shape, minval=-1.0, maxval=1.0)
    wild = EXTREMES[jax.random.randint(ext_key, (n,), 0, EXTREMES.shape[0])]
    return jnp.where(extreme[:, None], wild[:, None], fine)


def make_block(benv: BatchedEnv, steps: int) -> Any:
    """Jitted ``block(state, key) -> (state, counters)`` over ``steps`` env steps."""

    def body(carry: Any, key: jax.Array) -> tuple[Any, None]:
        state, c = carry
        nxt = benv.step(state, soak_actions(benv, key))
        bad_obs = jnp.sum(~jnp.isfinite(nxt.obs)) + jnp.sum(~jnp.isfinite(nxt.info["final_obs"]))
        c = {
            "nonfinite_obs": c["nonfinite_obs"] + bad_obs.astype(jnp.int32),
            "nonfinite_reward": c["nonfinite_reward"]
            + jnp.sum(~jnp.isfinite(nxt.reward)).astype(jnp.int32),
            "diverged": c["diverged"] + jnp.sum(nxt.info["diverged"]).astype(jnp.int32),
            "nan_actions": c["nan_actions"] + jnp.sum(nxt.info["nan_actions"]).astype(jnp.int32),
            "episodes": c["episodes"] + jnp.sum(nxt.done).astype(jnp.int32),
            "max_abs_obs": jnp.maximum(c["max_abs_obs"], jnp.max(jnp.abs(nxt.obs))),
        }
        return (nxt, c), None

    def block(state: Any, key: jax.Array) -> tuple[Any, dict[str, jax.Array]]:
        zero = jnp.zeros((), jnp.int32)
        c0 = {
            k: zero
            for k in ("nonfinite_obs", "nonfinite_reward", "diverged", "nan_actions", "episodes")
        }
        c0["max_abs_obs"] = jnp.zeros((), jnp.float32)
        keys = jax.random.split(key, steps)
        (state, c), _ = jax.lax.scan(body, (state, c0), keys, unroll=benv.scan_unroll)
        return state, c

    return jax.jit(block, donate_argnums=0)


def soak_task(
    env_id: str, num_envs: int, block: int, max_steps: int, seconds: float, seed: int
) -> dict[str, Any]:
    benv = jaxenvs.make(env_id, num_envs=num_envs)
    assert isinstance(benv, BatchedEnv)
    run = make_block(benv, block)
    key = jax.random.key(seed)
    reset_key, key = jax.random.split(key)
    state = jax.jit(benv.reset)(reset_key)
    totals = {"nonfinite_obs": 0, "nonfinite_reward": 0, "diverged": 0, "nan_actions": 0}
    totals["episodes"] = 0
    max_abs_obs = 0.0
    series: list[tuple[int, float, float]] = []  # (env steps, seconds, RSS MiB)
    steps, t0 = 0, time.perf_counter()
    compile_s = None
    while steps < max_steps:
        key, block_key = jax.random.split(key)
        state, c = run(state, block_key)
        c = jax.device_get(c)
        steps += block * num_envs
        for k in totals:
            totals[k] += int(c[k])
        max_abs_obs = max(max_abs_obs, float(c["max_abs_obs"]))
        elapsed = time.perf_counter() - t0
        if compile_s is None:
            compile_s = elapsed
        series.append((steps, round(elapsed, 2), round(rss_mb(), 1)))
        if totals["nonfinite_obs"] or totals["nonfinite_reward"]:
            break
        if elapsed - compile_s >= seconds:
            break
    wall = time.perf_counter() - t0
    rss = np.array([s[2] for s in series])
    after = rss[1:] if len(rss) > 1 else rss
    steady_steps = steps - block * num_envs
    return {
        "env_id": env_id,
        "num_envs": num_envs,
        "block_steps": block,
        "env_steps": steps,
        "seconds": round(wall, 1),
        "first_block_seconds (compile)": round(compile_s or 0.0, 1),
        "steps_per_second_after_compile": round(steady_steps / max(wall - (compile_s or 0), 1e-9)),
        **totals,
        "max_abs_obs": max_abs_obs,
        "rss_mb_after_first_block": float(after[0]),
        "rss_mb_last": float(rss[-1]),
        "rss_mb_max_after_first_block": float(after.max()),
        "rss_growth_mb_after_first_block": round(float(rss[-1] - after[0]), 1),
        "rss_series": series[:: max(1, len(series) // 20)] + [series[-1]],
        "ok": totals["nonfinite_obs"] == 0 and totals["nonfinite_reward"] == 0,
    }


def write_json(path: str, argv: list[str] | None, results: list[dict[str, Any]]) -> None:
    args = ["benchmarks/soak.py", *(sys.argv[1:] if argv is None else argv)]
    title = "env steps under random and extreme actions: non-finite values, divergence, memory"
    results_io.write(path, results_io.record(path, title, results, argv=args))


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    p.add_argument("--tasks", nargs="*", help="env ids (default: every registered id)")
    p.add_argument("--steps", type=float, default=1e8, help="env steps per task (all envs)")
    p.add_argument(
        "--seconds", type=float, default=3600.0, help="time budget per task, after the compile"
    )
    p.add_argument("--num-envs", type=int, default=128)
    p.add_argument("--block", type=int, default=200, help="env steps per env per compiled block")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--out", help=results_io.HELP)
    args = p.parse_args(argv)
    tasks = args.tasks or jaxenvs.list_envs()
    results = []
    for env_id in tasks:
        r = soak_task(env_id, args.num_envs, args.block, int(args.steps), args.seconds, args.seed)
        results.append(r)
        print(
            f"{env_id:22s} {r['env_steps']:>12,d} steps in {r['seconds']:7.1f} s "
            f"({r['steps_per_second_after_compile']:,} steps/s after compile) "
            f"diverged {r['diverged']:,} nan_actions {r['nan_actions']:,} "
            f"episodes {r['episodes']:,} non-finite obs/reward "
            f"{r['nonfinite_obs']}/{r['nonfinite_reward']} max|obs| {r['max_abs_obs']:.3g} "
            f"RSS {r['rss_mb_after_first_block']:.0f} -> {r['rss_mb_last']:.0f} MiB",
            flush=True,
        )
        if args.out:  # after every task, so a long soak cut short keeps what it did
            write_json(args.out, argv, results)
    return 0 if all(r["ok"] for r in results) else 1


if __name__ == "__main__":
    sys.exit(main())
