"""Where a HexapodWalk-v0 policy falls in its first seconds, by the target's start bearing.

Drives a run's greedy policy (``walker_seeds.load_policy``; full or slim run directory) in
``--envs`` envs with the default physics and a target 50 m away for ``--steps`` control
steps, and reports how many envs fell (the task's default termination) in each band of
the target's initial bearing in the body frame (0 = straight ahead, 180 = behind), with
the peak roll, pitch and yaw rates of the envs that fell and of those that did not.

    python benchmarks/studies/walker_start_falls.py RUN --steps 40     # the first 2 s
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))  # benchmarks/
import walker_seeds  # noqa: E402

BANDS = (0, 45, 90, 135, 181)  # degrees of |bearing|


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=(__doc__ or "").splitlines()[0])
    parser.add_argument("run_dir")
    parser.add_argument("--physics", choices=("mjx", "c"), default=None)
    parser.add_argument("--envs", type=int, default=256)
    parser.add_argument("--steps", type=int, default=40, help="control steps (0.05 s each)")
    parser.add_argument("--seed", type=int, default=123)
    args = parser.parse_args(argv)

    env, act = walker_seeds.eval_env(args.run_dir, args.physics)
    n = args.envs
    params = env.default_params.replace(target_range=jnp.asarray([50.0, 50.0], jnp.float32))

    @jax.jit
    def rollout(key: jax.Array):  # type: ignore[no-untyped-def]
        state = jax.vmap(env.reset, in_axes=(0, None))(jax.random.split(key, n), params)

        def body(carry, _):  # type: ignore[no-untyped-def]
            s, up = carry
            a = jax.vmap(act)(s.obs, jax.random.split(s.key[0], n))
            s = jax.vmap(env.step, in_axes=(0, 0, None))(s, a, params)
            return (s, up & ~s.terminated), (s.data.qvel[:, 3:6], up)

        carry = (state, jnp.ones(n, bool))
        (_, up), (rates, alive) = jax.lax.scan(body, carry, None, length=args.steps)
        return state.obs[:, 46:49], up, rates, alive

    direction, up, rates, alive = (np.asarray(x) for x in rollout(jax.random.key(args.seed)))
    fell = ~up
    bearing = np.abs(np.degrees(np.arctan2(direction[:, 1], direction[:, 0])))
    peak = np.abs(np.where(alive[..., None], rates, 0.0)).max(0)  # (n, 3) while up
    out = {
        "seconds": args.steps * env.control_dt,
        "envs": n,
        "fell": int(fell.sum()),
        "fallers_bearing_deg": sorted(int(b) for b in bearing[fell]),
        "by_bearing": [
            {
                "bearing_deg": [lo, min(hi, 180)],
                "envs": int(((bearing >= lo) & (bearing < hi)).sum()),
                "fell": int((fell & (bearing >= lo) & (bearing < hi)).sum()),
            }
            for lo, hi in zip(BANDS[:-1], BANDS[1:], strict=True)
        ],
    }
    for i, axis in enumerate(("roll", "pitch", "yaw")):
        out[f"peak_{axis}_rate_median_fell"] = (
            round(float(np.median(peak[fell, i])), 2) if fell.any() else None
        )
        out[f"peak_{axis}_rate_median_stayed_up"] = round(float(np.median(peak[~fell, i])), 2)
    for key, value in out.items():
        print(f"{key}: {json.dumps(value)}")


if __name__ == "__main__":
    main()
