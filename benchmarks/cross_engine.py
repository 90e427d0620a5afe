"""Train each PPO config on the CPU default engine, then evaluate it under both engines.

For every shipped ``ppo_<ID>.yaml`` (or the ids given): ``jaxenvs train ID --algo ppo``
(``physics="auto"``: the task's CPU engine), then ``jaxenvs eval RUN --physics mjx`` and
``--physics c`` with the same episodes and seed. A policy that only works on the engine it
trained on shows up as a gap between the two columns. Writes one JSON row per id.

    python benchmarks/cross_engine.py --ids CartPole-v0 Reacher-v0 --out runs/cross \\
        --json cross_engine_ppo_cpu2
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import results_io

from jaxenvs.run import runner


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=(__doc__ or "").splitlines()[0])
    parser.add_argument("--ids", nargs="+", default=None, help="env ids (default: CPU configs)")
    parser.add_argument("--out", default="runs/cross", help="where the run directories go")
    parser.add_argument("--episodes", type=int, default=20, help="eval episodes per seed")
    parser.add_argument("--json", default=None, help=results_io.HELP)
    args = parser.parse_args(argv)
    ids = args.ids or [
        "CartPole-v0",
        "CartpoleStayUp-v0",
        "CartpoleBalance-v0",
        "CartpoleSwingup-v0",
        "Reacher-v0",
        "HexapodOneLeg-v0",
    ]
    rows = []
    for env_id in ids:
        resolved = runner.resolve_config(env_id, "ppo", train_overrides={"video": False})
        run_dir = Path(args.out) / env_id
        t0 = time.perf_counter()
        summary = runner.train(resolved, run_dir, quiet=True)
        row = {
            "env_id": env_id,
            "trained_physics": summary["physics"],
            "train_wall_s": round(time.perf_counter() - t0, 1),
            "env_steps": summary["env_steps"],
            "train_eval_return": summary["eval_mean_return"],
        }
        for physics in ("mjx", "c"):
            res = runner.evaluate_run(run_dir, args.episodes, physics=physics)
            row[f"eval_{physics}"] = round(res["mean_return"], 3)
            row[f"eval_{physics}_std"] = round(res["std_return"], 3)
        print(json.dumps(row), flush=True)
        rows.append(row)
        if args.json:  # after every id, so that a long run keeps what it has
            title = "PPO configs trained on the CPU default engine, evaluated under MJX and C"
            results_io.write(args.json, results_io.record(args.json, title, rows))


if __name__ == "__main__":
    main()
