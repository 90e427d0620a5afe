"""``jaxenvs robot ID --listen tcp://HOST:PORT [--key-file FILE]``: the task's robot
simulated in MuJoCo C in real time behind the TCP link (:mod:`jaxenvs.deploy.simrobot`);
beyond the loopback only with a key (or ``--insecure``)."""

from __future__ import annotations

import argparse
import sys

from jaxenvs.cli import checks

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
        "--insecure",
        action="store_true",
        help="listen beyond this computer without a key (anyone who reaches the port drives it)",
    )


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
    world = simrobot.build_world(args.env_id, args.seed)
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
