"""A terrain task's policy on flat ground made three ways: a plane, and an all-flat
heightfield of 2.5 cm cells (the terrain's) or of 10 cm cells, under MuJoCo C or MJX.

Flat ground is flat however it is made, so a policy that walks on the plane and falls
(or tracks worse) on the flat heightfield does so because of the heightfield's contact
(``hfield_normals.py`` shows MuJoCo C's contact normals tilting on flat cells). The run's
greedy policy (a ``HexapodWalkRough-v0`` or ``HexapodJoystickRough-v0`` run, set up as
``rough_seeds.py eval`` sets it up: default fall rule, no pushes or action noise, the
run's observation noise and filter) drives ``--envs`` envs for 20 s with default physics:
on the plane, the flat task (``HexapodWalk-v0``, its targets 1-3 m from the body, or
``HexapodJoystick-v0``, its commands redrawn every 5 s) with the run's config; on a
heightfield, the terrain task with the run's config, one terrain type (``flat``) and that
``terrain_spacing``. One row per ground: ``ground``, ``physics``, ``envs`` and the task's
figures of ``rough_seeds.py`` (``fell_fraction``, and ``speed`` and
``targets_per_minute`` or ``tracking_error_lin`` and ``tracking_error_yaw``).

    JAX_PLATFORMS=cpu python benchmarks/flat_ground.py RUN --physics c --json walker_ground_cpu2
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
from jaxenvs.scenes import HFIELD_CONTACTS
from jaxenvs.tasks.hexapod.joystick import HexapodJoystick, JoystickConfig
from jaxenvs.tasks.hexapod.rough import HexapodJoystickRough, RoughCarry, TerrainTask
from jaxenvs.tasks.hexapod.walk import HexapodWalk, WalkConfig

SECONDS = 20.0
#: each ground: its name and the heightfield's sample spacing (m; None: the plane)
GROUNDS = (
    ("plane", None),
    ("flat heightfield, 2.5 cm cells", 0.025),
    ("flat heightfield, 10 cm cells", 0.1),
)


def on_ground(rough: TerrainTask, spacing: float | None, steps: int) -> Any:
    """The env of one ground (module docstring), episodes longer than ``steps``."""
    c = rough.config
    if spacing is None:
        flat_task, flat_config = (
            (HexapodJoystick, JoystickConfig)
            if isinstance(rough, HexapodJoystickRough)
            else (HexapodWalk, WalkConfig)
        )
        names = {f.name for f in dataclasses.fields(flat_config)} - {"target_distance"}
        flat = flat_config(**{k: getattr(c, k) for k in names})
        return flat_task(dataclasses.replace(flat, episode_length=steps + 1))
    config = dataclasses.replace(
        c, terrain_types=("flat",), terrain_spacing=spacing, episode_length=steps + 1
    )
    return type(rough)(config)


def measure(
    run: str, physics: str | None, n: int, seed: int, hfield_contact: str | None = None
) -> tuple[str, list[dict[str, Any]]]:
    """The run's task id and one row per ground (module docstring)."""
    env_id, rough, act = rough_seeds.eval_env(run, physics, hfield_contact=hfield_contact)
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
        contact = "plane" if spacing is None else rough.config.hfield_contact
        row = {"ground": name, "physics": env.physics, "hfield_contact": contact, "envs": n}
        rows.append(row | figures)
        print(json.dumps(rows[-1]), flush=True)
    return env_id, rows


def main() -> None:
    parser = argparse.ArgumentParser(description=(__doc__ or "").splitlines()[0])
    parser.add_argument("run_dir")
    parser.add_argument("--physics", choices=("mjx", "c"), default=None)
    parser.add_argument("--envs", type=int, default=280)
    parser.add_argument("--seed", type=int, default=123)
    parser.add_argument(
        "--hfield-contact",
        choices=HFIELD_CONTACTS,
        default=None,
        help="MuJoCo C's heightfield collider (default: the run's config's)",
    )
    parser.add_argument("--json", metavar="NAME", help=results_io.HELP)
    args = parser.parse_args()
    env_id, rows = measure(args.run_dir, args.physics, args.envs, args.seed, args.hfield_contact)
    if args.json:
        rec = results_io.record(
            args.json,
            f"{env_id}'s policy on flat ground: a plane and flat heightfields",
            rows,
            engine=rows[0]["physics"],
        )
        results_io.write(args.json, rec)


if __name__ == "__main__":
    main()
