"""``jaxenvs view``: MuJoCo's interactive viewer on an env, driven by hand, at random, or
by a trained policy.

``jaxenvs view Reacher-v0`` opens the viewer; drag the Control sliders (right panel) to
move the actuators yourself. ``--random`` plays random actions; ``--policy RUN_DIR``
plays the greedy policy of a run written by ``jaxenvs train`` (on the run's own env
config; a run directory that keeps only the greedy policy, ``policy.npz``, instead of
``checkpoint.npz`` plays that). Episodes restart from a fresh random state when they end.
A task that takes commands (``HexapodJoystick-v0``) is driven from the keyboard: Up/Down,
Left/Right and ``,``/``.`` step its command, Backspace zeroes it
(:class:`jaxenvs.render.viewer.CommandKeys`). Needs a display; without one it says so in one line
and points to ``jaxenvs render``.
"""

from __future__ import annotations

import argparse
from typing import Any

from jaxenvs.cli import checks

HELP = "open MuJoCo's interactive viewer: drive the actuators by hand, --random or --policy"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("env_id", metavar="ID", help="registered env id (see `jaxenvs list`)")
    how = parser.add_mutually_exclusive_group()
    how.add_argument("--random", action="store_true", help="play uniform random actions")
    how.add_argument("--policy", metavar="RUN_DIR", help="play the policy of this training run")
    parser.add_argument("--seed", type=int, default=0, help="PRNG seed (default 0)")
    parser.add_argument(
        "--steps", type=int, help="close after this many control steps (default: when closed)"
    )
    parser.add_argument("--fast", action="store_true", help="do not slow down to real time")


def _policy(run_dir: str, env_id: str) -> tuple[Any, Any]:
    """The run's env and greedy ``act_fn(obs, key)``; the run must be of ``env_id``."""
    from jaxenvs.run import runner

    run_env_id, env, act_fn = runner.load_policy(run_dir)
    if run_env_id != env_id:
        raise ValueError(f"{run_dir} is a run of {run_env_id}, not {env_id}")
    return env, act_fn


def run(args: argparse.Namespace) -> int:
    from jaxenvs.cli import UserError
    from jaxenvs.render import viewer

    if not viewer.display_available():
        raise UserError(viewer.no_display_message(args.env_id))
    checks.int_flag("--steps", args.steps, 1)
    checks.int_flag("--seed", args.seed, 0)
    import jaxenvs

    act_fn = None
    if args.policy:
        env, act_fn = _policy(args.policy, args.env_id)
        mode = "policy"
    else:
        env = jaxenvs.make(args.env_id)
        mode = "random" if args.random else "manual"
    if viewer.drivable(env):
        print("keys: Up/Down forward speed, Left/Right yaw rate, ,/. sideways, Backspace stop")
    player = viewer.view(
        env, mode, act_fn, seed=args.seed, steps=args.steps, realtime=not args.fast
    )
    print(f"viewer closed after {player.episodes} episode(s)")
    if player.keys is not None:
        print(f"last command: {[round(float(x), 3) for x in player.keys.command]}")
    return 0
