"""``jaxenvs eval``: greedy evaluation of a trained run from its checkpoint."""

from __future__ import annotations

import argparse
import json

from jaxenvs.commands import checks, engine_args
from jaxenvs.config import INT_MAX

HELP = "evaluate the greedy policy of a run directory (return mean/std, optional video)"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("run_dir", metavar="DIR", help="a run directory written by jaxenvs train")
    parser.add_argument("--episodes", type=int, default=20, help="episodes per seed")
    parser.add_argument("--seed", type=int, help="evaluation seed (default: the run's seed + 1)")
    parser.add_argument("--video", metavar="OUT.mp4", help="render one greedy episode")
    parser.add_argument("--json", action="store_true", help="print the result as JSON")
    engine_args.add(parser)


def run(args: argparse.Namespace) -> int:
    from jaxenvs.agents import restore

    checks.int_flag("--episodes", args.episodes, 1, 10**6)
    checks.int_flag("--seed", args.seed, 0, INT_MAX - 1)  # the default is the run's seed + 1
    result = restore.evaluate_run(
        args.run_dir, args.episodes, args.seed, args.video, physics=args.physics
    )
    if args.json:
        print(json.dumps(result, indent=2))
        return 0
    print(
        f"{result['algo']} on {result['env_id']} (physics {result['physics']}): return "
        f"{result['mean_return']:.2f} +- {result['std_return']:.2f} over "
        f"{result['episodes']} episodes"
    )
    if args.video:
        print(f"video: {result['video']}" if result["video"] else result["video_error"])
    return 0
