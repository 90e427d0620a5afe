"""A run's training chunk compiled at XLA's default backend level (3) and at 1, on a CPU.

For each ``TASK:PHYSICS`` (its shipped PPO config), each level in its own process, the
rounds alternating the order: the run's init (as ``jaxenvs train`` compiles it), then the
chunk over one seed lowered and compiled with jaxenvs' options plus
``xla_backend_optimization_level`` (nothing added for ``default``: XLA's level 3), and run
``--chunks`` times from init's state. Rows: ``lower_s``, ``compile_s``, ``run_s`` (the
chunks' wall, waited for), ``seconds_per_chunk`` and the last chunk's ``mean_return``. No
compile cache is used.

    JAX_PLATFORMS=cpu python benchmarks/chunk_options.py CartPole-v0:c Reacher-v0:c \\
        --rounds 4 --json chunk_options_cpu2
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import time
from typing import Any

import results_io

#: the levels compared: a label and the option added (None: XLA's default, level 3; the
#: result file of 2026-12-02 labels it "-O2")
LEVELS = {"default": None, "-O1": 1}


def job(task: str, physics: str, level: int | None, chunks: int) -> dict[str, Any]:
    """One process's row: compile and run ``task``'s chunk under ``physics``."""
    import jax
    import numpy as np

    from jaxenvs.core import xla
    from jaxenvs.run import programs, run_config

    resolved = run_config.with_physics(run_config.resolve_config(task, "ppo"), physics)
    env, trainer = run_config.build(resolved)
    state = xla.jit_once(programs.over_seeds(trainer.init, 1))(run_config.seed_keys(0, 1))
    extra = {} if level is None else {"xla_backend_optimization_level": level}
    chunk = xla.jit(programs.over_seeds(trainer.chunk, 1), compiler_options=extra)
    start = time.perf_counter()
    lowered = chunk.lower(state)
    lower_s = time.perf_counter() - start
    start = time.perf_counter()
    compiled = lowered.compile()
    compile_s = time.perf_counter() - start
    start = time.perf_counter()
    for _ in range(chunks):
        state, metrics = compiled(state)
    jax.block_until_ready(state)
    run_s = time.perf_counter() - start
    return {
        "env_id": task,
        "physics": env.physics,
        "lower_s": round(lower_s, 3),
        "compile_s": round(compile_s, 3),
        "run_s": round(run_s, 3),
        "chunks": chunks,
        "seconds_per_chunk": round(run_s / chunks, 4),
        "mean_return": float(np.nanmean(np.asarray(metrics["mean_return"]))),
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("runs", nargs="*", help="TASK:PHYSICS (physics c or mjx)")
    parser.add_argument("--rounds", type=int, default=2)
    parser.add_argument("--chunks", type=int, default=16)
    parser.add_argument("--job", nargs=4, help=argparse.SUPPRESS)
    parser.add_argument("--json", help=results_io.HELP)
    args = parser.parse_args()
    if args.job:
        task, physics, level, chunks = args.job
        row = job(task, physics, None if level == "none" else int(level), int(chunks))
        print(json.dumps(row), flush=True)
        return
    rows = []
    for k in range(args.rounds):
        for spec in args.runs:
            task, physics = spec.split(":")
            order = list(LEVELS.items())
            for label, level in order if k % 2 == 0 else order[::-1]:
                argv = [task, physics, "none" if level is None else str(level), str(args.chunks)]
                done = subprocess.run(
                    [sys.executable, __file__, "--job", *argv],
                    check=True,
                    capture_output=True,
                    text=True,
                    timeout=3600,
                )
                row = {**json.loads(done.stdout.strip().splitlines()[-1]), "level": label}
                rows.append({**row, "round": k})
                print(rows[-1], flush=True)
    if args.json:
        title = "A run's training chunk compiled at XLA's default level and at -O1 on a CPU"
        results_io.write(args.json, results_io.record(args.json, title, rows))


if __name__ == "__main__":
    main()
