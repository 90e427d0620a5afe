"""``jaxenvs robot ID --listen tcp://HOST:PORT [--key-file FILE]``: the task's robot
simulated in MuJoCo C in real time behind the TCP link (:mod:`jaxenvs.deploy.simrobot`);
beyond the loopback only with a key (or ``--insecure``). A terrain task's robot stands on
the task's terrain; ``--terrain LEVEL[:TYPE]`` starts it on a tile of that level (and
type)."""

from __future__ import annotations

import argparse
import sys
from typing import Any

from jaxenvs.cli import checks
from jaxenvs.config import ConfigError

HELP = "simulate a task's robot in real time behind a TCP link (for jaxenvs deploy)"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("env_id", metavar="ID", help="a task over a robot (see `jaxenvs list`)")
    parser.add_argument(
        "--listen",
        default="tcp://127.0.0.1:5555",
        metavar="tcp://HOST:PORT",
        help="where to listen (port 0: a free port; default tcp://127.0.0.1:5555)",
    )
    parser.add_argument("--noise", type=float, default=0.0, help="sensor noise std scale")
    parser.add_argument("--latency-ms", type=float, default=0.0, help="delay of each message")
    parser.add_argument("--jitter-ms", type=float, default=0.0, help="extra uniform delay")
    parser.add_argument(
        "--watchdog", type=int, default=5, help="hold after this many periods with no command"
    )
    parser.add_argument("--seconds", type=float, default=0.0, help="end each run after this")
    parser.add_argument("--once", action="store_true", help="exit when the first client leaves")
    parser.add_argument("--seed", type=int, default=0, help="initial states, noise, delays")
    parser.add_argument(
        "--realtime", action="store_true", help="run under SCHED_FIFO (Linux, CAP_SYS_NICE)"
    )
    parser.add_argument(
        "--key-file",
        metavar="FILE",
        help="serve only a client that proves it holds this key (not readable by every user)",
    )
    parser.add_argument(
        "--terrain",
        metavar="LEVEL[:TYPE]",
        help="a terrain task: start on a tile of this level, of this terrain type if named",
    )
    parser.add_argument(
        "--insecure",
        action="store_true",
        help="listen beyond this computer without a key (anyone who reaches the port drives it)",
    )


def terrain_overrides(env_id: str, value: str | None) -> dict[str, Any]:
    """The config fields that start every episode of ``env_id`` on a tile of ``value``
    (``LEVEL`` or ``LEVEL:TYPE``; ``None``: none); :class:`ConfigError` naming
    ``--terrain`` for a task without a terrain, a level or a type it does not have."""
    if value is None:
        return {}
    from jaxenvs.registry import spec

    config = spec(env_id).config
    levels, types = getattr(config, "levels", None), getattr(config, "terrain_types", None)
    if levels is None or types is None:
        raise ConfigError(f"--terrain: {env_id} has no terrain")
    level, _, kind = value.partition(":")
    if not level.isdigit() or int(level) >= levels:
        raise ConfigError(f"--terrain: the level must be 0..{levels - 1}, got {level!r}")
    if kind and kind not in types:
        raise ConfigError(f"--terrain: no type {kind!r} in {env_id}'s ({', '.join(types)})")
    out: dict[str, Any] = {"min_init_level": int(level), "max_init_level": int(level)}
    return out | ({"spawn_types": (kind,)} if kind else {})


def run(args: argparse.Namespace) -> int:
    from jaxenvs.deploy import auth, simrobot

    checks.float_flag("--noise", args.noise, 0.0, 1e3)
    checks.float_flag("--latency-ms", args.latency_ms, 0.0, 1e4)
    checks.float_flag("--jitter-ms", args.jitter_ms, 0.0, 1e4)
    checks.float_flag("--seconds", args.seconds, 0.0, 1e7)
    checks.int_flag("--watchdog", args.watchdog, 1, 10**6)
    checks.int_flag("--seed", args.seed, 0)
    key = auth.read_key(args.key_file) if args.key_file else None
    simrobot.check_listen(args.listen, key, args.insecure)  # before the world is built
    terrain = terrain_overrides(args.env_id, args.terrain)
    world = simrobot.build_world(args.env_id, args.seed, terrain)
    opts = simrobot.LinkOptions(
        noise=args.noise,
        latency_ms=args.latency_ms,
        jitter_ms=args.jitter_ms,
        watchdog=args.watchdog,
        seconds=args.seconds,
        once=args.once,
        seed=args.seed,
    )
    if args.realtime:
        from jaxenvs.deploy.loop import raise_priority

        print(f"robot: {raise_priority()}", file=sys.stderr, flush=True)
    return simrobot.serve(world, args.listen, opts, key, args.insecure)
