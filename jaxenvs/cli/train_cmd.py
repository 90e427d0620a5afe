"""``jaxenvs train``: train an agent on a task from a YAML config and command-line flags."""

from __future__ import annotations

import argparse
import dataclasses
import importlib
import signal
import sys
import time
from pathlib import Path

from jaxenvs.cli import checks, engine_args

HELP = "train an agent (qlearning, sarsa, ppo) and write its results to a run directory"

#: flags that set a field of the agent config / of the run config
AGENT_FLAGS = {"num_envs": "num_envs", "total_steps": "total_steps", "scaling": "scaling"}
RUN_FLAGS = {"seed": "seed", "num_seeds": "num_seeds", "eval_episodes": "eval_episodes"}


def add_arguments(parser: argparse.ArgumentParser) -> None:
    from jaxenvs.run import distributed
    from jaxenvs.run.run_config import ALGORITHMS

    parser.add_argument("env_id", nargs="?", help="env id (or env.id in the config file)")
    parser.add_argument("--algo", choices=sorted(ALGORITHMS), help="the learning algorithm")
    parser.add_argument(
        "--config",
        metavar="FILE",
        help="YAML file: env/agent/train sections, or the name of a shipped config "
        "(e.g. ppo_HexapodJoystick-v0.link.yaml)",
    )
    parser.add_argument("--seed", type=int, help="base seed (default 0)")
    parser.add_argument("--num-seeds", type=int, help="independent seeds trained together")
    parser.add_argument("--num-envs", type=int, help="parallel envs per seed")
    parser.add_argument(
        "--total-steps", type=int, help="env steps per seed (rounded up to whole chunks)"
    )
    parser.add_argument("--eval-episodes", type=int, help="greedy episodes per seed at the end")
    parser.add_argument(
        "--devices",
        type=int,
        help="split the env batch over the first N devices (default: all; N must divide "
        "--num-envs)",
    )
    parser.add_argument(
        "--scaling",
        choices=("strong", "weak"),
        help="PPO over several devices: split --num-envs over them (strong, the default) "
        "or give each device --num-envs envs (weak)",
    )
    parser.add_argument("--out", metavar="DIR", help="run directory (default runs/ENV-ALGO-TIME)")
    parser.add_argument("--resume", metavar="DIR", help="continue the run in DIR")
    parser.add_argument("--no-video", action="store_true", help="do not render video.mp4")
    parser.add_argument(
        "--no-compile-cache", action="store_true", help="do not use the persistent compile cache"
    )
    parser.add_argument("--quiet", action="store_true", help="no progress bar or notices")
    engine_args.add(parser)
    distributed.add_arguments(parser)


def _enable_compile_cache(args: argparse.Namespace) -> None:
    if args.no_compile_cache:
        return
    try:
        cache = importlib.import_module("jaxenvs.run.compile_cache")
    except ModuleNotFoundError:
        return
    cache.enable()


def _interrupt(signum: int, frame: object) -> None:
    raise KeyboardInterrupt


def run(args: argparse.Namespace) -> int:
    from jaxenvs.cli import UserError
    from jaxenvs.run import distributed, loop, run_config

    distributed.initialize_from(args)  # before the first JAX operation
    checks.int_flag("--devices", args.devices, 1, 2**16)
    if args.resume:
        given = ("env_id", "algo", "config", "out", "physics", *AGENT_FLAGS, *RUN_FLAGS)
        clash = [f for f in given if getattr(args, f) is not None]
        if clash:
            raise UserError(
                f"--resume continues with {args.resume}/config.yaml; drop "
                + ", ".join(c if c == "env_id" else "--" + c.replace("_", "-") for c in clash)
            )
        resolved = run_config.load_run_config(args.resume)
        out = Path(args.resume)
        resume = True
    else:
        train_overrides: dict[str, object] = {k: getattr(args, f) for f, k in RUN_FLAGS.items()}
        if args.no_video:
            train_overrides["video"] = False
        resolved = run_config.resolve_config(
            args.env_id,
            args.algo,
            args.config,
            agent_overrides={k: getattr(args, f) for f, k in AGENT_FLAGS.items()},
            train_overrides=train_overrides,
        )
        resolved = run_config.with_physics(resolved, args.physics)
        stamp = time.strftime("%Y%m%d-%H%M%S")
        out = Path(args.out or f"runs/{resolved.env_id}-{resolved.algo}-{stamp}")
        out = distributed.process_out_dir(out)  # process k > 0 of several: its own
        if (out / run_config.CHECKPOINT_FILE).exists():
            raise UserError(f"{out} already holds a run; use --resume {out} or another --out")
        resume = False
    if args.no_video and resume:
        resolved = dataclasses.replace(
            resolved, train=dataclasses.replace(resolved.train, video=False)
        )
    _enable_compile_cache(args)  # only once the command is known to be valid
    previous = signal.signal(signal.SIGTERM, _interrupt)  # SIGTERM stops it as Ctrl-C does
    try:
        summary = loop.train(resolved, out, resume=resume, quiet=args.quiet, devices=args.devices)
    except KeyboardInterrupt:
        if args.quiet:  # the runner's notice was silenced; the way on is not
            saved = (out / run_config.CHECKPOINT_FILE).is_file()
            way_on = f"continue with: jaxenvs train --resume {out}"
            print(way_on if saved else "nothing was saved: start the run again", file=sys.stderr)
        raise
    finally:
        signal.signal(signal.SIGTERM, previous)
    line = (
        f"{resolved.algo} on {resolved.env_id}: eval return {summary['eval_mean_return']:.1f} "
        f"+- {summary['eval_std_return']:.1f} ({summary['eval_episodes']} episodes), "
        f"{summary['env_steps']} steps, {summary['episodes']} episodes, "
        f"{summary['wall_seconds']:.1f} s; overall score {summary['overall_score']:.1f}"
    )
    if summary.get("best_100_score") is not None:
        line += f", best-100 score {summary['best_100_score']:.1f}"
    print(line)
    print(f"results in {out}", file=sys.stderr if args.quiet else sys.stdout)
    return 0
