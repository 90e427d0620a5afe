"""How often a rough joystick (or walker) policy falls on stepping stones, by level and by
the depth of the pit under the stones.

Each run's greedy policy (``rough_seeds.eval_env``: the task's default fall rule, pushes
and action noise off, the curriculum off) drives ``--envs`` envs, all on the stepping-stone
tile of one level, for one episode of ``--seconds`` under ``--physics`` (MuJoCo C by
default), commands redrawn on the task's schedule; ``fell_fraction`` is the share of envs
that fell. ``--pits`` lists the pits to measure: ``levelled`` (the generator's default, as
deep as the level's stair riser) and depths in metres (the same depth at every level)::

    JAX_PLATFORMS=cpu python benchmarks/stones_falls.py runs/rough_s0 \\
        --levels 0 1 2 3 4 5 --pits 0.2 --json NAME

One row per run, pit and level: ``run``, ``seed``, ``pit`` (``levelled`` or the depth),
``level``, ``pit_depth`` (m, at that level), ``stone_size``, ``stone_gap`` (m), ``envs``,
``seconds``, ``fell_fraction``.
"""

from __future__ import annotations

import argparse
import dataclasses
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
import results_io
import rough_seeds

from jaxenvs.core import BatchedEnv
from jaxenvs.run import runner
from jaxenvs.tasks.hexapod.rough import RoughCarry, TerrainTask


def with_pit(env: TerrainTask, pit: float | None) -> TerrainTask:
    """``env`` on its terrain with the stones' pit ``pit`` m deep at every level (``None``:
    the config's own terrain)."""
    if pit is None:
        return env
    base = type(env.config)

    class FixedPit(base):  # type: ignore[misc, valid-type]
        def terrain_config(self) -> Any:
            return dataclasses.replace(base.terrain_config(self), pit_depth=(pit, pit))

    fields = {f.name: getattr(env.config, f.name) for f in dataclasses.fields(env.config)}
    return type(env)(FixedPit(**fields))


def falls(env: TerrainTask, act: Any, level: int, envs: int, steps: int, seed: int) -> float:
    """The share of ``envs`` envs on the stepping stones of ``level`` that fell within
    ``steps`` control steps."""
    column = list(env.config.terrain_types).index("stepping_stones")
    carry = RoughCarry(
        level=jnp.full(envs, level, jnp.int32), column=jnp.full(envs, column, jnp.int32)
    )
    keys = jax.random.split(jax.random.key(seed), envs)
    state = BatchedEnv(env, envs, devices=1).fresh_starts(keys, None, carry)
    params = jax.tree.map(lambda x: jnp.broadcast_to(x, (envs, *x.shape)), env.default_params)
    out = rough_seeds.trajectories(env, act, {}, state, params, steps)
    return float(1.0 - np.asarray(out["after"])[-1].mean())


def measure(run_dir: str, args: argparse.Namespace) -> list[dict[str, Any]]:
    """The rows of one run (module docstring)."""
    _, env, act = rough_seeds.eval_env(run_dir, args.physics)
    seed = runner.load_run_config(run_dir).train.seed
    rows = []
    for pit in args.pits:
        pitted = with_pit(env, None if pit == "levelled" else float(pit))
        terrain = pitted.terrain.config
        assert terrain is not None
        steps = round(args.seconds / pitted.control_dt)
        for level in args.levels:
            rows.append(
                {
                    "run": run_dir.rstrip("/").split("/")[-1],
                    "seed": seed,
                    "pit": pit,
                    "level": level,
                    "pit_depth": round(terrain.at("pit_depth", level), 4),
                    "stone_size": round(terrain.at("stone_size", level), 4),
                    "stone_gap": round(terrain.at("stone_gap", level), 4),
                    "envs": args.envs,
                    "seconds": args.seconds,
                    "fell_fraction": falls(pitted, act, level, args.envs, steps, args.seed),
                }
            )
            print(rows[-1], flush=True)
    return rows


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=(__doc__ or "").splitlines()[0])
    parser.add_argument("run_dirs", nargs="+")
    parser.add_argument("--levels", type=int, nargs="+", default=[5, 9])
    parser.add_argument("--pits", nargs="+", default=["levelled"], help="'levelled' or metres")
    parser.add_argument("--physics", choices=("mjx", "c"), default="c")
    parser.add_argument("--envs", type=int, default=32)
    parser.add_argument("--seconds", type=float, default=20.0)
    parser.add_argument("--seed", type=int, default=5)
    parser.add_argument("--json", required=True, help=results_io.HELP)
    args = parser.parse_args(argv)
    for pit in args.pits:
        if pit != "levelled" and not 0 < float(pit) <= 1:
            raise SystemExit(f"--pits: {pit!r} is neither 'levelled' nor a depth in (0, 1] m")
    rows = [row for run in args.run_dirs for row in measure(run, args)]
    rec = results_io.record(
        args.json,
        "Falls on stepping stones by level and pit depth",
        rows,
        description="the 2-core development VM",
        engine=args.physics,
    )
    results_io.write(args.json, rec)


if __name__ == "__main__":
    main()
