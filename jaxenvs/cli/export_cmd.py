"""``jaxenvs export``: a PPO run's greedy policy as ONNX or as a numpy-only ``.npz``."""

from __future__ import annotations

import argparse

HELP = "export the greedy policy of a PPO run directory as ONNX or npz (numpy runtime)"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("run_dir", metavar="RUN", help="a run directory written by jaxenvs train")
    parser.add_argument("--format", required=True, metavar="onnx|npz", help="the file format")
    parser.add_argument("--out", metavar="FILE", help="output (default RUN/exported_policy.FMT)")
    parser.add_argument(
        "--seed", type=int, help="the seed of a multi-seed run (default: the best evaluated)"
    )


def run(args: argparse.Namespace) -> int:
    from jaxenvs.deploy import export

    export.output_path(args.run_dir, args.format, args.out)  # fail before restoring
    export.check_seed(args.run_dir, args.seed)
    path, policy = export.export(args.run_dir, args.format, args.out, args.seed)
    meta = policy.metadata
    kind = (
        f"{policy.action_size} discrete" if policy.discrete else f"{policy.action_size} continuous"
    )
    print(
        f"wrote {path}: {meta['env_id']} seed {meta['seed']}, obs {policy.observation_size} "
        f"-> {kind} actions, control period {policy.control_dt:g} s"
    )
    return 0
