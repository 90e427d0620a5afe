"""Exported policies against the JAX policy, for every shipped PPO config, on real rollouts.

For each run directory (given, or trained here with ``--train DIR``): ``jaxenvs export RUN
--format onnx`` and ``--format npz``, then ``--obs`` observations (10,240 by default) from
greedy rollouts of the run's own policy in its env (auto-resetting envs, fresh random
starts), and the actions of the ONNX file (onnxruntime, CPU) and of the npz (the numpy
runtime) set against ``jaxenvs eval``'s (the trainer's ``act``, jitted). A row passes when
the largest difference is at most 1e-5 and no discrete choice differs.

``--train DIR`` trains every shipped ``ppo_<ID>.yaml`` (or ``--ids``) for ``--chunks``
chunks under MuJoCo's C engine with at most 64 envs and 2 updates per chunk, keeping the
config's network, normalisation and rollout length (what the export depends on); the
policies need not be good for parity, and the result file says they are short runs.
``--chunks 0`` trains the shipped length.

    python benchmarks/export_parity.py --train runs/export --json export_parity_cpu2
    python benchmarks/export_parity.py runs/walker-h200 --physics mjx
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path
from typing import Any

import numpy as np
import results_io

from jaxenvs.deploy import export, parity
from jaxenvs.deploy.runtime import NumpyPolicy
from jaxenvs.run import runner

TOL = 1e-5
SHORT_ENVS, SHORT_UPDATES = 64, 2


def shipped_ids() -> list[str]:
    """The env ids of every shipped PPO config."""
    configs = Path(export.__file__).resolve().parent.parent / "configs"
    return sorted(p.stem.removeprefix("ppo_") for p in configs.glob("ppo_*.yaml"))


def train_short(env_id: str, out: Path, chunks: int) -> Path:
    """A run of the shipped config of ``env_id`` under the C engine: ``chunks`` chunks of at
    most 64 envs and 2 updates (0: the shipped length and sizes)."""
    base = runner.resolve_config(env_id, "ppo")
    agent: dict[str, Any] = {}
    if chunks:
        num_envs = min(base.agent.num_envs, SHORT_ENVS)
        per_chunk = num_envs * base.agent.num_steps * SHORT_UPDATES
        agent = {"num_envs": num_envs, "updates_per_chunk": SHORT_UPDATES}
        agent["total_steps"] = chunks * per_chunk
    resolved = runner.resolve_config(
        env_id, "ppo", agent_overrides=agent, train_overrides={"video": False, "eval_episodes": 4}
    )
    resolved = runner.with_physics(resolved, "c")
    runner.train(resolved, out, quiet=True)
    return out


def check_run(run: Path, num_obs: int, physics: str | None) -> list[dict[str, Any]]:
    """One row per format: the parity of RUN's exported files on rollout observations."""
    start = time.perf_counter()
    paths = {fmt: export.export(run, fmt)[0] for fmt in export.FORMATS}
    export_s = (time.perf_counter() - start) / len(paths)
    numpy_policy = NumpyPolicy.load(paths["npz"])
    meta = numpy_policy.metadata
    policy = parity.jax_policy(run, int(meta["seed"]), physics)
    obs = parity.rollout_observations(policy, num_obs)
    reference = policy.actions(obs)
    actions = {"onnx": parity.onnx_actions(paths["onnx"], obs), "npz": numpy_policy(obs)}
    resolved = runner.load_run_config(run)
    summary = json.loads((run / runner.SUMMARY_FILE).read_text())
    steps = summary["env_steps"] // resolved.train.num_seeds
    shipped = runner.resolve_config(meta["env_id"], "ppo").agent.total_steps
    rows = []
    for fmt, act in actions.items():
        row = parity.compare(reference, act, policy.env.discrete, TOL)
        rows.append(
            {
                "env_id": meta["env_id"],
                "run": run.name,
                "format": fmt,
                "training": "shipped length" if steps >= shipped else "short",
                "env_steps_trained": steps,
                "eval_mean_return": summary["eval_mean_return"],
                "actor_hidden": list(resolved.agent.actor_hidden),
                "normalize_obs": resolved.agent.normalize_obs,
                "discrete": policy.env.discrete,
                "rollout_physics": policy.env.physics,
                **row,
                "distinct_observations": int(np.unique(obs, axis=0).shape[0]),
                "passed": row["mismatches"] == 0 and row["max_abs_diff"] <= TOL,
                "file_bytes": paths[fmt].stat().st_size,
                "export_s": round(export_s, 2),
            }
        )
        print(json.dumps(rows[-1]), flush=True)
    return rows


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=(__doc__ or "").splitlines()[0])
    parser.add_argument("runs", nargs="*", help="PPO run directories to check")
    parser.add_argument("--train", metavar="DIR", help="first train short runs here")
    parser.add_argument("--ids", nargs="+", help="with --train: these ids (default: all)")
    parser.add_argument("--chunks", type=int, default=2, help="with --train (0: shipped length)")
    parser.add_argument("--obs", type=int, default=10_240, help="rollout observations per run")
    parser.add_argument("--physics", help="the rollouts' engine (default: each run's)")
    parser.add_argument("--json", default=None, help=results_io.HELP)
    parser.add_argument("--note", default="", help="added to the result file's notes")
    parser.add_argument(
        "--machine", default="the shared 2-core development machine", help="its description"
    )
    args = parser.parse_args(argv)
    runs = [Path(r) for r in args.runs]
    if args.train:
        for env_id in args.ids or shipped_ids():
            runs.append(train_short(env_id, Path(args.train) / env_id, args.chunks))
    rows = [row for run in runs for row in check_run(run, args.obs, args.physics)]
    missing = sorted(set(shipped_ids()) - {r["env_id"] for r in rows})
    notes = (
        f"Parity passes at max |diff| <= {TOL} and no differing discrete choice. "
        + (
            f"Runs trained here are SHORT ({args.chunks} chunks of at most {SHORT_ENVS} envs x "
            f"{SHORT_UPDATES} updates under physics c, the shipped network and normalisation): "
            "parity needs a policy's structure, not a good one. "
            if args.train and args.chunks
            else ""
        )
        + (f"Not checked: {', '.join(missing)}." if missing else "Every shipped PPO config.")
        + (f" {args.note}" if args.note else "")
    )
    if args.json:
        title = "Exported PPO policies (ONNX, npz) against the JAX policy on rollouts"
        import jax  # noqa: F401  (loaded: machine() reports the device)
        import onnx
        import onnxruntime

        extra = {"onnx": onnx.__version__, "onnxruntime": onnxruntime.__version__}
        rec = results_io.record(
            args.json, title, rows, description=args.machine, notes=notes, extra=extra
        )
        results_io.write(args.json, rec)
    print(notes)


if __name__ == "__main__":
    main()
