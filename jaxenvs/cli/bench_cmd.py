"""``jaxenvs bench``: env steps/s over a batch sweep, optionally beside the peers.

    jaxenvs bench --tasks CartPole-v0 Reacher-v0 --batches 256 4096 --peers \\
        --json bench.json --plot bench.png

Our env is compiled at every (task, batch, mode) first; then ours and the peers are timed
in interleaved rounds (medians), so a busy machine slows both alike. The ratio table
(ours at its best batch, full auto-resetting step, over each peer) is printed last. The
peers' harness is not part of the package: ``--peers`` loads ``benchmarks/peers.py`` from
the source checkout the package runs from, and is a one-line error elsewhere.
"""

from __future__ import annotations

import argparse
import importlib.util
import json
import sys
from collections.abc import Callable
from pathlib import Path
from types import ModuleType
from typing import TYPE_CHECKING, Any

from jaxenvs import files
from jaxenvs.cli import checks

if TYPE_CHECKING:
    from jaxenvs.bench import Runner

HELP = "measure env steps/s over a batch sweep, optionally beside Gymnasium/EnvPool/MuJoCo"


def _positive(text: str) -> int:
    value = int(text)
    if value < 1:
        raise argparse.ArgumentTypeError(f"must be a positive integer, got {text}")
    return value


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--tasks", nargs="+", default=None, help="env ids (default: all)")
    parser.add_argument(
        "--batches", nargs="+", type=_positive, default=[1, 256, 4096], help="num_envs sweep"
    )
    parser.add_argument(
        "--modes",
        nargs="+",
        default=["full", "functional"],
        help="full (auto-resetting step), functional (env.step alone), physics (sim only)",
    )
    parser.add_argument("--steps", type=_positive, default=100, help="env steps per call")
    parser.add_argument("--repeats", type=_positive, default=5, help="timed rounds (median)")
    parser.add_argument("--target-s", type=float, default=0.3, help="seconds per timed call")
    parser.add_argument(
        "--peers",
        action="store_true",
        help="also time the peers (benchmarks/peers.py of a checkout)",
    )
    parser.add_argument("--peer-envs", type=_positive, default=256, help="EnvPool/rollout batch")
    parser.add_argument(
        "--threads",
        type=_positive,
        default=None,
        help="CPU cores to use (default: all usable): the C engine's and the peers' threads, "
        "and on a CPU one XLA device per two cores for MJX",
    )
    parser.add_argument(
        "--physics",
        nargs="+",
        choices=("auto", "mjx", "c"),
        default=None,
        help="engines to time side by side (default: mjx and c on a CPU, mjx elsewhere)",
    )
    parser.add_argument("--json", default=None, metavar="FILE", help="write results as JSON")
    parser.add_argument("--plot", default=None, metavar="FILE", help="write a log-log plot")
    parser.add_argument(
        "--devices", type=_positive, default=None, help="split the batch over N devices"
    )


def _validate(args: argparse.Namespace, ids: list[str]) -> list[str]:
    import jax

    from jaxenvs import registry
    from jaxenvs.bench import MODES

    checks.float_flag("--target-s", args.target_s, 1e-3, 3600.0)
    tasks = args.tasks or ids
    for task in tasks:
        registry.spec(task)  # unknown ids raise; "module:Id" imports module (registering Id)
    bad = [m for m in args.modes if m not in MODES]
    if bad:
        raise ValueError(f"unknown mode {bad[0]!r}; choose from {', '.join(MODES)}")
    if args.devices is not None:
        if args.devices > jax.device_count():
            raise ValueError(
                f"--devices {args.devices}: only {jax.device_count()} "
                f"{jax.default_backend()} device(s) visible"
            )
        uneven = [b for b in args.batches if b % args.devices]
        if uneven:
            raise ValueError(f"--devices {args.devices} does not divide batch {uneven[0]}")
    for path in (args.json, args.plot):
        if path is not None:
            with open(path, "a"):
                pass
    return tasks


#: the peers' harness in a source checkout (this file is jaxenvs/cli/bench_cmd.py)
PEERS_FILE = Path(__file__).resolve().parents[2] / "benchmarks" / "peers.py"


def peer_harness() -> ModuleType:
    """:data:`PEERS_FILE`, loaded as a module; a ``ValueError`` (one line) where the package
    runs without a source checkout (an installed wheel)."""
    path = PEERS_FILE
    spec = importlib.util.spec_from_file_location("jaxenvs_bench_peers", path)
    if not path.is_file() or spec is None or spec.loader is None:
        raise ValueError(
            f"--peers needs a source checkout of jaxenvs: the peers' harness is "
            f"benchmarks/peers.py there, not part of the installed package (no {path})"
        )
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module  # its dataclasses look their module up while executing
    spec.loader.exec_module(module)
    return module


def _runners(
    args: argparse.Namespace,
    tasks: list[str],
    log: Callable[[str], None],
    peers: ModuleType | None,
) -> tuple[list[Runner], list[dict[str, Any]]]:
    """Ours compiled at every (task, engine, batch, mode); with ``peers`` (the harness),
    each task's peers.

    Returns the runners and the peers that could not run here (as result dicts)."""
    import jax

    from jaxenvs import bench, machine

    engines = args.physics or (["mjx", "c"] if jax.default_backend() == "cpu" else ["mjx"])
    threads = args.threads or machine.cpu_threads()
    runners: list[Runner] = []
    skipped: list[dict[str, Any]] = []
    for task in tasks:
        for physics in dict.fromkeys(engines):
            for b in args.batches:
                for mode in args.modes:
                    log(f"compiling {task} x{b} {mode} ({physics})")
                    devices = args.devices if mode == "full" else None
                    runners.append(bench.prepare_ours(task, b, mode, args.steps, devices, physics))
        if peers is not None:
            log(f"preparing peers of {task}")
            for p in peers.peer_runners(task, args.peer_envs, max(args.batches), threads):
                if isinstance(p, bench.Runner):
                    runners.append(p)
                else:
                    skipped.append(p.as_dict())
    return runners, skipped


def _results_table(results: list[dict[str, Any]]) -> list[list[Any]]:
    from jaxenvs.bench import is_ours

    rows: list[list[Any]] = [["task", "who", "variant", "envs", "env steps/s", "first call s"]]
    for r in results:
        if r.get("skipped"):
            rows.append([r["task"], r["name"], r["variant"], "-", "skipped: " + r["reason"], "-"])
            continue
        first = r.get("first_call_s")
        who = f"jaxenvs ({r.get('physics', 'mjx')})" if is_ours(r) else r["name"]
        rows.append(
            [
                r["task"],
                who,
                r["variant"],
                r["num_envs"],
                f"{r['env_steps_per_s']:,.0f}",
                "-" if first is None else f"{first:.1f}",
            ]
        )
    return rows


def _ratio_table(ratio_rows: list[dict[str, Any]]) -> list[list[Any]]:
    table: list[list[Any]] = [["task", "ours (envs)", "peer", "peer steps/s", "ours / peer"]]
    for q in ratio_rows:
        table.append(
            [
                q["task"],
                f"{q['ours']:,.0f} ({q['physics']}, {q['our_envs']})",
                q["peer"],
                f"{q['peer_steps_per_s']:,.0f}",
                f"{q['ratio']:.2f}x",
            ]
        )
    return table


def run(args: argparse.Namespace) -> int:
    import jaxenvs
    from jaxenvs import bench

    tasks = _validate(args, jaxenvs.list_envs())
    peers = peer_harness() if args.peers else None

    def log(msg: str) -> None:
        print(f"# {msg}", file=sys.stderr, flush=True)

    info = bench.machine()
    print(f"# {info['host']} {info['device']} x{info['device_count']} jax {info['jax']}")
    runners, skipped = _runners(args, tasks, log, peers)
    log(f"timing {len(runners)} runners, {args.repeats} interleaved rounds")
    results = bench.time_runners(runners, args.repeats, args.target_s, log) + skipped
    print(bench.format_table(_results_table(results)))
    ratio_rows: list[dict[str, Any]] = [] if peers is None else peers.ratios(results)
    if ratio_rows:
        print()
        print(bench.format_table(_ratio_table(ratio_rows)))
    out = {
        "machine": info,
        "args": {k: v for k, v in vars(args).items() if not k.startswith("_")},
        "peak_rss_mib": bench.peak_rss_mib(),
        "device_peak_mib": bench.device_peak_mib(),
        "results": results,
        "ratios": ratio_rows,
    }
    if args.json:
        files.write_text(args.json, json.dumps(out, indent=2) + "\n")
    if args.plot:
        from jaxenvs.bench.plot import plot

        plot(results, args.plot)
    return 0
