"""Why a rough joystick policy falls: each fall's rule, and how high the body rides.

Plays the same episodes as ``rough_seeds.py eval`` (the same envs, seed, levels and
physics groups; its ``fell_fraction`` per type is this script's ``falls`` over ``envs``),
reading the body's ``height`` above the ground below it at every step. A fall is *low*
when that height was under the task's ``min_height`` at the step the episode ended, else
*tilted* (the up axis past ``min_upright``). Per terrain type, over the steps an env was
up: the median, 5th and 1st percentile of the height::

    JAX_PLATFORMS=cpu python benchmarks/fall_causes.py runs/rough_s0 --physics c

Prints one line per group (default or randomised physics, middle or top level) and type.
"""

from __future__ import annotations

import argparse

import numpy as np
import rough_seeds


def causes(run_dir: str, physics: str, envs: int, seed: int, seconds: float) -> list[str]:
    """The lines the module docstring describes, for one run."""
    env_id, env, act = rough_seeds.eval_env(run_dir, physics)
    if env_id != "HexapodJoystickRough-v0":
        raise SystemExit(f"{run_dir} is a run of {env_id}, not of HexapodJoystickRough-v0")
    env, steps = rough_seeds.with_episode(env, seconds)
    out = rough_seeds.rollout(env, act, {"height": "height"}, envs, steps, seed)
    c = env.config
    types = np.arange(envs) % len(c.terrain_types)
    lines = [f"{run_dir} ({env.physics}; min_height {c.min_height} m)"]
    for params, level, x in rough_seeds.groups(out, envs):
        up, after, height = x["up"], x["after"], x["height"]
        ended = up & ~after  # (steps, envs): the step each fallen env's episode ended
        for t, name in enumerate(c.terrain_types):
            sel = types == t
            h_end = height[:, sel][ended[:, sel]]
            low = int((h_end < c.min_height).sum())
            h_up = height[:, sel][after[:, sel]]
            p50, p5, p1 = np.percentile(h_up, [50, 5, 1])
            lines.append(
                f"  {params:10s} {level:3s} {name:16s} falls {len(h_end):2d}/{sel.sum()} "
                f"(low {low}, tilted {len(h_end) - low})  height {p50:.3f} / {p5:.3f} / {p1:.3f}"
            )
    return lines


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=(__doc__ or "").splitlines()[0])
    parser.add_argument("run_dirs", nargs="+")
    parser.add_argument("--physics", choices=("mjx", "c"), default="c")
    parser.add_argument("--envs", type=int, default=280, help="envs per group (default 280)")
    parser.add_argument("--seed", type=int, default=123)
    parser.add_argument("--seconds", type=float, default=20.0)
    args = parser.parse_args(argv)
    for run in args.run_dirs:
        print("\n".join(causes(run, args.physics, args.envs, args.seed, args.seconds)))


if __name__ == "__main__":
    main()
