"""A batched random-action rollout of every cartpole task inside one jitted lax.scan.

python examples/rollout.py [--num-envs 4096] [--steps 200]
"""

from __future__ import annotations

import argparse
import time

import jax
import jax.numpy as jnp

import jaxenvs


def rollout(env_id: str, num_envs: int, steps: int) -> None:
    benv = jaxenvs.make(env_id, num_envs=num_envs)

    def run(key):
        reset_key, run_key = jax.random.split(key)
        state = benv.reset(reset_key)

        def body(carry, k):
            state = carry
            if benv.discrete:
                action = jax.random.randint(k, (num_envs,), 0, benv.action_size)
            else:
                action = jax.random.uniform(k, (num_envs, benv.action_size), minval=-1.0)
            state = benv.step(state, action)
            return state, (state.done, state.info["final_return"])

        keys = jax.random.split(run_key, steps)
        # scan_unroll: the task's measured best unroll of the rollout loop
        state, (done, ret) = jax.lax.scan(body, state, keys, unroll=benv.scan_unroll)
        episodes = done.sum()
        mean_ret = jnp.where(done, ret, 0.0).sum() / jnp.maximum(episodes, 1)
        return episodes, mean_ret

    run = jax.jit(run)
    t0 = time.perf_counter()
    jax.block_until_ready(run(jax.random.key(0)))
    compile_s = time.perf_counter() - t0
    t0 = time.perf_counter()
    episodes, mean_ret = jax.block_until_ready(run(jax.random.key(1)))
    wall = time.perf_counter() - t0
    print(
        f"{env_id:20s} {num_envs} envs x {steps} steps: {num_envs * steps / wall:12,.0f} "
        f"env steps/s (first call {compile_s:.1f} s); {int(episodes)} episodes ended, "
        f"mean return of a random policy {float(mean_ret):.1f}"
    )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--num-envs", type=int, default=4096)
    parser.add_argument("--steps", type=int, default=200)
    parser.add_argument("--tasks", nargs="*", default=None)
    args = parser.parse_args()
    print(f"jax {jax.__version__} on {jax.devices()[0].platform}")
    for env_id in args.tasks or jaxenvs.list_envs():
        rollout(env_id, args.num_envs, args.steps)


if __name__ == "__main__":
    main()
