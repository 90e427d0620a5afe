"""A rough walker's policy on flat ground made three ways: a plane, and an all-flat
heightfield of 2.5 cm cells (the terrain's) or of 10 cm cells, under MuJoCo C or MJX.

Flat ground is flat however it is made, so a policy that walks on the plane and falls on
the flat heightfield falls because of the heightfield's contact (``hfield_normals.py``
shows MuJoCo C's contact normals tilting on flat cells). The run's greedy policy (a
``HexapodWalkRough-v0`` run, set up as ``rough_seeds.py eval`` sets it up: default fall
rule, no action noise, the run's observation noise) drives ``--envs`` envs for 20 s with
default physics: on the plane, ``HexapodWalk-v0`` with the run's config (its targets 1-3 m
from the body, drawn anew on arrival); on a heightfield, ``HexapodWalkRough-v0`` with the
run's config, one terrain type (``flat``) and that ``terrain_spacing`` (its targets about
the tile's centre). One row per ground: ``ground``, ``physics``, ``envs``,
``fell_fraction``, ``speed`` (m/s toward the target, while up) and ``targets_per_minute``.

    JAX_PLATFORMS=cpu python benchmarks/walker_ground.py RUN --physics c --json walker_ground_cpu2
"""

from __future__ import annotations

import argparse
import dataclasses
import json
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
import results_io
import rough_seeds

from jaxenvs.core import BatchedEnv
from jaxenvs.tasks.hexapod.rough import RoughCarry
from jaxenvs.tasks.hexapod.walk import HexapodWalk, WalkConfig
from jaxenvs.tasks.hexapod.walk_rough import HexapodWalkRough

SECONDS = 20.0
#: each ground: its name and the heightfield's sample spacing (m; None: the plane)
GROUNDS = (
    ("plane", None),
    ("flat heightfield, 2.5 cm cells", 0.025),
    ("flat heightfield, 10 cm cells", 0.1),
)


def on_ground(rough: HexapodWalkRough, spacing: float | None, steps: int) -> Any:
    """The env of one ground (module docstring), episodes longer than ``steps``."""
    c = rough.config
    if spacing is None:
        names = {f.name for f in dataclasses.fields(WalkConfig)} - {"target_distance"}
        flat = WalkConfig(**{k: getattr(c, k) for k in names})
        return HexapodWalk(dataclasses.replace(flat, episode_length=steps + 1))
    config = dataclasses.replace(
        c, terrain_types=("flat",), terrain_spacing=spacing, episode_length=steps + 1
    )
    return HexapodWalkRough(config)


def measure(run: str, physics: str | None, n: int, seed: int) -> list[dict[str, Any]]:
    """One row per ground (module docstring)."""
    env_id, rough, act = rough_seeds.eval_env(run, physics)
    if not isinstance(rough, HexapodWalkRough):
        raise SystemExit(f"{run} is a run of {env_id}, not HexapodWalkRough-v0")
    steps = round(SECONDS / rough.control_dt)
    keys = jax.random.split(jax.random.key(seed), n)
    rows = []
    for name, spacing in GROUNDS:
        env = on_ground(rough, spacing, steps)
        carry = None
        if spacing is not None:
            carry = RoughCarry(level=jnp.zeros(n, jnp.int32), column=jnp.zeros(n, jnp.int32))
        state = BatchedEnv(env, n, devices=1).fresh_starts(keys, None, carry)
        params = jax.tree.map(lambda x: jnp.broadcast_to(x, (n, *x.shape)), env.default_params)
        out = rough_seeds.trajectories(
            env, act, rough_seeds.STEP_INFO[env_id], state, params, steps
        )
        figures = rough_seeds.figures({k: np.asarray(v) for k, v in out.items()}, SECONDS / 60)
        rows.append({"ground": name, "physics": env.physics, "envs": n} | figures)
        print(json.dumps(rows[-1]), flush=True)
    return rows


def main() -> None:
    parser = argparse.ArgumentParser(description=(__doc__ or "").splitlines()[0])
    parser.add_argument("run_dir")
    parser.add_argument("--physics", choices=("mjx", "c"), default=None)
    parser.add_argument("--envs", type=int, default=280)
    parser.add_argument("--seed", type=int, default=123)
    parser.add_argument("--json", metavar="NAME", help=results_io.HELP)
    args = parser.parse_args()
    rows = measure(args.run_dir, args.physics, args.envs, args.seed)
    if args.json:
        rec = results_io.record(
            args.json,
            "HexapodWalkRough-v0's policy on flat ground: a plane and flat heightfields",
            rows,
            engine=rows[0]["physics"],
        )
        results_io.write(args.json, rec)


if __name__ == "__main__":
    main()
