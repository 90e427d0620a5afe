"""The rough task's env steps/s over the flat joystick's, in one process.

Each batch size steps ``HexapodJoystick-v0`` (flat) and ``HexapodJoystickRough-v0`` (its
default terrain, the contact solve its config picks for the engine: ``solver: auto``), and
with ``--solvers`` the rough task with each named solver and with ``--max-contacts`` with
each MJX contact budget (``max_contacts``; 0: every slot) and with ``--hfield-contacts``
with each of MuJoCo C's heightfield colliders (``hfield_contact``) too, side by side: a jitted
``lax.scan`` of ``--steps`` auto-resetting batched steps with uniform random actions, the
state donated, timed over ``--rounds`` rounds interleaved across the variants (median).
Rows: one per variant and batch, with ``x_flat``, its rate over the flat task's at that
batch in the same process.

    python benchmarks/terrain_throughput.py --envs 1024 --physics c --solvers cg \
        --hfield-contacts mujoco --json terrain_throughput_cpu2
    python benchmarks/terrain_throughput.py --envs 8192 65536 --solvers cg \\
        --json terrain_throughput_gpu
    python benchmarks/terrain_throughput.py --envs 8192 65536 --physics mjx --max-contacts 0
"""

from __future__ import annotations

import argparse
import statistics
import time
from collections.abc import Callable
from typing import Any

import jax
import results_io

import jaxenvs
from jaxenvs.scenes import HFIELD_CONTACTS

FLAT, ROUGH = "HexapodJoystick-v0", "HexapodJoystickRough-v0"


def rollout(
    env_id: str, n: int, steps: int, physics: str, **overrides: Any
) -> tuple[Callable, Any]:
    """A jitted ``(state, key) -> state`` of ``steps`` batched steps, and the first state."""
    benv = jaxenvs.make(env_id, num_envs=n, physics=physics, **overrides)
    size = benv.env.action_size

    def run(state: Any, key: jax.Array) -> Any:
        def body(s: Any, k: jax.Array) -> tuple[Any, None]:
            return benv.step(s, jax.random.uniform(k, (n, size), minval=-1.0, maxval=1.0)), None

        return jax.lax.scan(body, state, jax.random.split(key, steps))[0]

    return jax.jit(run, donate_argnums=0), jax.jit(benv.reset)(jax.random.key(0))


def measure(
    n: int,
    steps: int,
    rounds: int,
    physics: str,
    solvers: list[str],
    caps: list[int],
    hfield_contacts: tuple[str, ...] = (),
) -> list[dict]:
    """Rows for batch ``n``: flat, rough (its config's defaults), rough with each of
    ``solvers``, with each of ``caps`` as its ``max_contacts`` (MJX's contact budget) and
    with each of ``hfield_contacts`` as its ``hfield_contact`` (MuJoCo C's collider)."""
    variants = [("flat", FLAT, {}), ("rough", ROUGH, {})]
    variants += [(f"rough_{s}", ROUGH, {"solver": s}) for s in solvers]
    variants += [(f"rough_contacts{c}", ROUGH, {"max_contacts": c}) for c in caps]
    variants += [(f"rough_{h}_hfield", ROUGH, {"hfield_contact": h}) for h in hfield_contacts]
    runs, rows = {}, {}
    for name, env_id, overrides in variants:
        fn, state = rollout(env_id, n, steps, physics, **overrides)
        start = time.perf_counter()
        state = jax.block_until_ready(fn(state, jax.random.key(1)))
        runs[name] = [fn, state]
        rows[name] = {
            "variant": name,
            "task": env_id,
            "num_envs": n,
            "physics": physics,
            "first_call_s": time.perf_counter() - start,
            "rates": [],
            **overrides,
        }
    for r in range(rounds):
        for name, run in runs.items():
            start = time.perf_counter()
            run[1] = jax.block_until_ready(run[0](run[1], jax.random.key(2 + r)))
            rows[name]["rates"].append(n * steps / (time.perf_counter() - start))
    flat = statistics.median(rows["flat"]["rates"])
    for row in rows.values():
        row["env_steps_per_s"] = statistics.median(row["rates"])
        row["x_flat"] = row["env_steps_per_s"] / flat
        print(
            f"{row['variant']:>14} {n:>7,} envs {row['env_steps_per_s']:>12,.0f} env steps/s"
            f"  x flat {row['x_flat']:.2f}  (first call {row['first_call_s']:.1f} s)",
            flush=True,
        )
    return list(rows.values())


def main() -> None:
    parser = argparse.ArgumentParser(description=(__doc__ or "").splitlines()[0])
    parser.add_argument("--envs", type=int, nargs="+", default=[1024])
    parser.add_argument("--steps", type=int, default=20, help="steps per timed call")
    parser.add_argument("--rounds", type=int, default=5)
    parser.add_argument("--physics", default="auto", choices=("auto", "mjx", "c"))
    parser.add_argument("--solvers", nargs="*", default=[], help="rough also with these")
    parser.add_argument(
        "--max-contacts",
        type=int,
        nargs="*",
        default=[],
        help="rough also with these max_contacts (0: every contact slot; MJX only, "
        "MuJoCo C keeps every contact)",
    )
    parser.add_argument(
        "--hfield-contacts",
        nargs="*",
        default=[],
        choices=HFIELD_CONTACTS,
        help="rough also with these hfield_contact (MuJoCo C's heightfield collider)",
    )
    parser.add_argument("--json", help=results_io.HELP)
    args = parser.parse_args()
    rows = [
        row
        for n in args.envs
        for row in measure(
            n,
            args.steps,
            args.rounds,
            args.physics,
            args.solvers,
            args.max_contacts,
            tuple(args.hfield_contacts),
        )
    ]
    if args.json:
        title = "HexapodJoystickRough-v0's env steps/s over HexapodJoystick-v0's, same process"
        results_io.write(args.json, results_io.record(args.json, title, rows))


if __name__ == "__main__":
    main()
