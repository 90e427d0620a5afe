"""Scale-out of PPO end to end: env steps/s of a task's training on 1 and N devices.

Each row trains a task's shipped PPO config through the runner's own programs
(:func:`jaxenvs.run.programs.build_programs`, as ``jaxenvs train --devices N`` runs it)
in one of three modes:

* ``weak``: the config's ``num_envs`` on every device (``scaling: weak``): N devices
  collect N times the data per update;
* ``strong``: the config's ``num_envs`` split over the devices;
* ``seeds``: N seeds, each trained on a device of its own (no cross-device traffic).

A row runs ``init``, a first chunk (compile and run: ``first_chunk_s``, less what of the
compile overlapped init, which a chunk in stages and, from 2026-12-03 on, a one-program
chunk on one device start before it; from the build's start to its end:
``to_first_chunk_s``), then, once the evaluator that the run loop starts
compiling after the first chunk has compiled, ``--chunks`` timed chunks;
``env_steps_per_s`` is the env steps of the timed chunks (every seed's) over their wall
time, compile excluded; ``train_seconds`` is the whole row's wall time, init, the first
chunk and the evaluator's compile included (files from before 2026-12-01 compiled the
evaluator beside the first chunk and did not wait for it; their one-seed rows also
traced the seed axis that one seed now goes without); ``speedup`` is over the one-device
row of the same task (for ``seeds``: one seed on one device). ``--chunk`` picks how a
one-device chunk runs (``staged``: its rollout's and learning's programs, compiled side by
side; ``one``: one program; ``auto``: as a run picks, staged on an accelerator; rows record
it as ``chunk``). ``--env-only`` adds a row of
the env alone on one device (random actions, the same batch, solver and randomisation),
for the ratio of PPO's rate to its env's.

    python benchmarks/scaling.py --tasks HexapodWalk-v0 --devices 1 2 --modes weak seeds \\
        --chunks 3 --env-only --json scaling_gpu

On a CPU, add ``XLA_FLAGS=--xla_force_host_platform_device_count=2`` to try the code path
(the "devices" then share the same cores, so expect no speed-up).
"""

from __future__ import annotations

import argparse
import time
from typing import Any

import jax
import results_io

from jaxenvs.core import BatchedEnv, sharding
from jaxenvs.run import programs, run_config
from jaxenvs.run.placement import resolve_scaling

MODES = ("weak", "strong", "seeds")


def _resolved(task: str, mode: str, devices: int, overrides: dict[str, Any]) -> Any:
    """The run config of one row, resolved for ``devices`` devices as a run resolves it."""
    agent = {**overrides, "scaling": "weak" if mode == "weak" else "strong"}
    seeds = devices if mode == "seeds" else 1
    train = {"num_seeds": seeds, "video": False, "eval_episodes": 1}
    r = run_config.resolve_config(task, "ppo", None, agent, train)
    return resolve_scaling(run_config.engine_resolved(r), devices)


#: ``--chunk``: how a one-device chunk runs (``programs.build_programs``' ``staged``)
CHUNKS = {"auto": None, "staged": True, "one": False}


def ppo_row(
    task: str,
    mode: str,
    devices: int,
    chunks: int,
    overrides: dict[str, Any],
    chunk: str = "auto",
) -> dict[str, Any]:
    """One row: PPO on ``task`` in ``mode`` over the first ``devices`` devices."""
    resolved = _resolved(task, mode, devices, overrides)
    t0 = time.perf_counter()
    progs = programs.build_programs(resolved, devices, CHUNKS[chunk])
    keys = run_config.seed_keys(0, resolved.train.num_seeds)
    template = progs.init_fn.eval_shape(keys)  # as the run loop does: the traces, then
    progs.chunk_fn.eval_shape(template)  # the compiles of a chunk in stages beside init's
    progs.start_chunk(template)
    state = jax.block_until_ready(progs.init_fn(keys))
    t1 = time.perf_counter()
    state, metrics = progs.chunk_fn(state)
    progs.start_evaluator()  # as the run loop does once the first chunk has compiled
    state, _ = jax.block_until_ready((state, metrics))
    first = time.perf_counter() - t1
    progs.evaluator.start().result()  # its compile must not share the timed chunks
    t2 = time.perf_counter()
    for _ in range(chunks):
        state, metrics = jax.block_until_ready(progs.chunk_fn(state))
    timed = time.perf_counter() - t2
    steps = progs.trainer.steps_per_chunk * chunks * resolved.train.num_seeds
    return {
        "task": task,
        "gpus": devices,
        "mode": mode,
        "chunk": "staged" if isinstance(progs.chunk_fn, programs.StagedChunk) else "one",
        "env_steps_per_s": steps / timed,
        "train_seconds": time.perf_counter() - t0,
        "first_chunk_s": first,
        "to_first_chunk_s": t1 + first - t0,
        "timed_chunks": chunks,
        "num_envs_total": resolved.agent.num_envs * resolved.train.num_seeds,
        "num_seeds": resolved.train.num_seeds,
        "loss": float(jax.device_get(metrics["loss"]).mean()),
        "device": jax.devices()[0].device_kind,
    }


def env_row(task: str, steps: int, repeats: int, overrides: dict[str, Any]) -> dict[str, Any]:
    """The env alone on one device at the config's batch, solver and randomisation."""
    resolved = _resolved(task, "strong", 1, overrides)
    env, _ = run_config.build(resolved)
    a = resolved.agent
    benv = BatchedEnv(env, a.num_envs, randomize=a.randomize, devices=1, compact_reset=False)
    reset, run = sharding.make_sharded_steps(benv, sharding.make_mesh(1), steps)
    keys = iter(jax.random.split(jax.random.key(0), repeats + 2))
    state = jax.block_until_ready(run(reset(next(keys)), next(keys)))
    t0 = time.perf_counter()
    for k in keys:
        state = jax.block_until_ready(run(state, k))
    wall = time.perf_counter() - t0
    return {
        "task": task,
        "gpus": 1,
        "mode": "env-only",
        "env_steps_per_s": a.num_envs * steps * repeats / wall,
        "train_seconds": None,
        "num_envs_total": a.num_envs,
        "device": jax.devices()[0].device_kind,
    }


def add_speedups(rows: list[dict[str, Any]]) -> None:
    """``speedup`` of each PPO row over the one-device PPO row of its task (in place);
    the env-only row gets the one-device PPO rate over its own (``ppo_over_env``)."""
    base = {
        r["task"]: r["env_steps_per_s"] for r in rows if r["gpus"] == 1 and r["mode"] != "env-only"
    }
    for r in rows:
        b = base.get(r["task"])
        if r["mode"] == "env-only":
            r["ppo_over_env"] = None if b is None else b / r["env_steps_per_s"]
        r["speedup"] = None if b is None or r["mode"] == "env-only" else r["env_steps_per_s"] / b


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=(__doc__ or "").splitlines()[0])
    parser.add_argument("--tasks", nargs="+", default=["HexapodWalk-v0"])
    parser.add_argument("--devices", nargs="+", type=int, default=[1, jax.device_count()])
    parser.add_argument("--modes", nargs="+", choices=MODES, default=["weak", "seeds"])
    parser.add_argument("--chunks", type=int, default=3, help="timed chunks a row")
    parser.add_argument("--num-envs", type=int, help="override the config's num_envs")
    parser.add_argument("--total-steps", type=int, help="override the config's total_steps")
    parser.add_argument("--chunk", choices=CHUNKS, default="auto", help="how a chunk runs")
    parser.add_argument("--env-only", action="store_true", help="add the env-alone row")
    parser.add_argument("--json", default=None, help=results_io.HELP)
    args = parser.parse_args(argv)
    overrides = {
        k: v for k, v in {"num_envs": args.num_envs, "total_steps": args.total_steps}.items() if v
    }
    print(
        f"# jax {jax.__version__}, {jax.device_count()} x {jax.devices()[0].device_kind}",
        flush=True,
    )
    rows: list[dict[str, Any]] = []

    def report(row: dict[str, Any]) -> None:
        rows.append(row)
        add_speedups(rows)
        print({k: v for k, v in row.items()}, flush=True)
        if args.json:
            title = (
                f"PPO end to end on {', '.join(args.tasks)} over {sorted(set(args.devices))} GPUs"
            )
            rec = results_io.record(args.json, title, rows, extra={"args": vars(args)})
            results_io.write(args.json, rec)

    for task in args.tasks:
        for n in sorted(set(args.devices)):
            for mode in args.modes if n > 1 else ["weak"]:
                report(ppo_row(task, mode, n, args.chunks, overrides, args.chunk))
        if args.env_only:
            report(env_row(task, 16 * 8, 3, overrides))


if __name__ == "__main__":
    main()
