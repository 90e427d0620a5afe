"""The ``--physics`` and ``--threads`` options shared by train, eval, bench and render."""

from __future__ import annotations

import argparse
import sys
from typing import Any

PHYSICS_HELP = (
    "physics engine: mjx, c (MuJoCo's C engine, CPU only) or auto (default: MJX on a GPU, "
    "the task's faster engine on a CPU; see `jaxenvs list`)"
)
THREADS_HELP = (
    "CPU cores to use (default: all usable): the C engine's threads, and on a CPU one "
    "XLA device per two cores for MJX"
)


def add(parser: argparse.ArgumentParser, physics_nargs: str | None = None) -> None:
    """Add ``--physics`` (one engine, or several with ``physics_nargs="+"``) and ``--threads``."""
    parser.add_argument(
        "--physics", nargs=physics_nargs, choices=("auto", "mjx", "c"), help=PHYSICS_HELP
    )
    parser.add_argument("--threads", type=_positive, default=None, help=THREADS_HELP)


def _positive(text: str) -> int:
    value = int(text)
    if not 1 <= value <= 2**16:
        raise argparse.ArgumentTypeError(f"must be an integer from 1 to 65536, got {text}")
    return value


def say(env: Any, quiet: bool = False) -> None:
    """Print :func:`jaxenvs.machine.describe` to stderr unless ``quiet``."""
    from jaxenvs import machine

    if not quiet:
        print(machine.describe(env), file=sys.stderr)
