"""A task metric at the END of greedy episodes of a trained run (e.g. the one-leg task's
final foot-tip distance), which ``summary.json`` (returns only) does not hold.

    python benchmarks/studies/final_metric.py runs/oneleg --metric distance --episodes 100

Runs ``--episodes`` greedy episodes of the run's best seed from fresh random starts for the
full episode length (tasks without termination; an episode that terminates early keeps
its metric from the terminating step) and prints the mean, median and max of
``info[METRIC]`` at each episode's last step.
"""

from __future__ import annotations

import argparse
import json

import jax
import jax.numpy as jnp
import numpy as np

from jaxenvs.run import runner


def final_metric(run_dir: str, metric: str, episodes: int, seed: int) -> np.ndarray:
    """``info[metric]`` at the last step of each of ``episodes`` greedy episodes."""
    _, env, act = runner.load_policy(run_dir)
    if metric not in env.metric_keys:
        raise SystemExit(f"{metric!r} is not a metric of this task; it has {env.metric_keys}")

    def episode(key: jax.Array) -> jax.Array:
        reset_key, act_key = jax.random.split(key)
        state = env.reset(reset_key)

        def body(carry, k):  # type: ignore[no-untyped-def]
            s, done, value = carry
            nxt = env.step(s, act(s.obs, k))
            value = jnp.where(done, value, nxt.info[metric])
            return (nxt, done | nxt.done, value), None

        init = (state, jnp.zeros((), bool), state.info[metric])
        keys = jax.random.split(act_key, env.episode_length)
        (_, _, value), _ = jax.lax.scan(body, init, keys)
        return value

    keys = jax.random.split(jax.random.key(seed), episodes)
    return np.asarray(jax.jit(jax.vmap(episode))(keys))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("run_dir")
    parser.add_argument("--metric", default="distance")
    parser.add_argument("--episodes", type=int, default=100)
    parser.add_argument("--seed", type=int, default=12345)
    args = parser.parse_args()
    values = final_metric(args.run_dir, args.metric, args.episodes, args.seed)
    print(
        json.dumps(
            {
                "run": args.run_dir,
                "metric": args.metric,
                "episodes": args.episodes,
                "mean": float(values.mean()),
                "median": float(np.median(values)),
                "max": float(values.max()),
            }
        )
    )


if __name__ == "__main__":
    main()
