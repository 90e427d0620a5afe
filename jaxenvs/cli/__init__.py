"""The ``jaxenvs`` command line: list, train, eval, compare, render, bench, view, export,
robot, deploy.

Each subcommand lives in its own module under ``jaxenvs.cli`` exposing
``HELP`` (one line), ``add_arguments(parser)`` and ``run(args) -> int``. Errors the user
can fix (bad id, bad config, unwritable output) print one line and exit 2; ``--debug``
shows the traceback instead.
"""

from __future__ import annotations

import argparse
import gc
import importlib
import sys
from collections.abc import Sequence

COMMANDS = (
    "list",
    "train",
    "eval",
    "compare",
    "render",
    "bench",
    "view",
    "export",
    "robot",
    "deploy",
)


def _module(name: str):  # type: ignore[no-untyped-def]
    return importlib.import_module(f"jaxenvs.cli.{name}_cmd")


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="jaxenvs",
        description="JAX-accelerated robot RL environments on MuJoCo MJX.",
    )
    parser.add_argument("--debug", action="store_true", help="show tracebacks on errors")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)
    for name in COMMANDS:
        mod = _module(name)
        p = sub.add_parser(name, help=mod.HELP, description=mod.HELP)
        mod.add_arguments(p)
        p.set_defaults(_run=mod.run)
    return parser


def _use_cores(args: argparse.Namespace) -> None:
    """Every command uses all usable cores unless ``--threads`` says otherwise; this runs
    before the command's first JAX operation (it fixes the CPU's XLA device count)."""
    from jaxenvs import machine

    machine.use_cores(getattr(args, "threads", None), strict=False)


class UserError(Exception):
    """An error the user can fix; printed as one line."""


def main(argv: Sequence[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        _use_cores(args)
        return int(args._run(args) or 0)
    except KeyboardInterrupt:
        print("interrupted", file=sys.stderr)
        return 130
    except (UserError, ValueError, TypeError, OSError) as err:
        if args.debug:
            raise
        msg = str(err).strip().splitlines()[0] if str(err).strip() else type(err).__name__
        print(f"jaxenvs {args.command}: error: {msg}", file=sys.stderr)
        return 2


def entry() -> int:
    """The process's entry point (the ``jaxenvs`` script and ``python -m jaxenvs``):
    :func:`main`'s exit code. Twice it moves every object alive at that point out of the
    garbage collector's view (``gc.freeze``): once the package is imported, so that the
    command's collections do not walk the modules, functions and tables that the imports
    made and that live as long as the process, and once :func:`main` has returned, so that
    the interpreter's exit does not walk them again. Only for a process that ends after
    it: the collector skips frozen objects for the rest of the process, so objects kept
    alive only by reference cycles among them are not finalized (atexit handlers still
    run; nothing of jaxenvs' needs more). Measured in benchmarks/NOTES.md, "A process's
    first and last second" and "The collector and the imports"."""
    gc.freeze()
    code = main()
    gc.freeze()
    return code


if __name__ == "__main__":
    sys.exit(entry())
