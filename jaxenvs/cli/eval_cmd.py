"""``jaxenvs eval``: greedy evaluation of a trained run from its checkpoint."""

from __future__ import annotations

import argparse
import json
import sys

from jaxenvs.cli import checks, engine_args
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
    """Print the evaluation; exit status 1 when the requested video could not be written
    (the evaluation is printed all the same, the failure in one line on stderr)."""
    from jaxenvs.run import restore

    checks.int_flag("--episodes", args.episodes, 1, 10**6)
    checks.int_flag("--seed", args.seed, 0, INT_MAX - 1)  # the default is the run's seed + 1
    if args.video is not None:
        from jaxenvs import render

        render.check_video_path(args.video)
    result = restore.evaluate_run(
        args.run_dir, args.episodes, args.seed, args.video, physics=args.physics
    )
    failed = args.video is not None and not result["video"]
    if args.json:
        print(json.dumps(result, indent=2))
    else:
        print(
            f"{result['algo']} on {result['env_id']} (physics {result['physics']}): return "
            f"{result['mean_return']:.2f} +- {result['std_return']:.2f} over "
            f"{result['episodes']} episodes"
        )
        if args.video and not failed:
            print(f"video: {result['video']}")
    if failed:
        print(f"jaxenvs eval: error: {result.get('video_error', 'no video')}", file=sys.stderr)
        return 1
    return 0
