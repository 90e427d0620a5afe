"""Raw physics steps/s of HexapodWalk-v0's device model under MJX's two GPU backends.

The same lean walker model (CG 6/3, pyramidal cone, 0.01 s Euler, as shipped), the same
standing start and the same random servo targets around the stance, stepped by
``mjx.step`` in a jitted ``scan`` over a ``vmap``: once with the JAX implementation
(``mjx.put_model(m, impl="jax")``, what the package uses) and once with MuJoCo Warp
(``impl="warp"``; needs ``warp-lang`` and ``mujoco-warp`` and an NVIDIA GPU). Prints
physics and env steps/s (5 physics steps per env step), the first call, and whether the
robots are still finite and standing at the end.

    python3 benchmarks/studies/walker_warp.py --batches 8192 65536 --impls jax warp
"""

from __future__ import annotations

import argparse
import statistics
import time

import jax
import jax.numpy as jnp
import numpy as np
from mujoco import mjx

import jaxenvs

STEPS = 50


def measure(impl: str, n: int) -> str:
    env = jaxenvs.make("HexapodWalk-v0")
    m = env.sim.physics_mj_model
    start = jax.jit(env.reset)(jax.random.key(0)).data
    ctrl0 = jnp.asarray(start.ctrl)
    lo, hi = m.actuator_ctrlrange[:, 0], m.actuator_ctrlrange[:, 1]
    mx = mjx.put_model(m, impl=impl)
    if impl == "warp":  # contacts share one buffer across worlds; 6 feet x 4 rows each
        d0 = mjx.make_data(m, impl="warp", naconmax=8 * n, njmax=32)
    else:
        d0 = mjx.make_data(mx)

    def init(_: jax.Array) -> mjx.Data:
        return mjx.forward(mx, d0.replace(qpos=start.qpos, qvel=jnp.zeros(m.nv), ctrl=ctrl0))

    def run(d: mjx.Data, key: jax.Array) -> mjx.Data:
        def body(d: mjx.Data, k: jax.Array) -> tuple[mjx.Data, None]:
            noise = jax.random.uniform(k, (n, m.nu), minval=-0.3, maxval=0.3)
            ctrl = jnp.clip(ctrl0 + noise, lo, hi)
            return jax.vmap(lambda d, u: mjx.step(mx, d.replace(ctrl=u)))(d, ctrl), None

        return jax.lax.scan(body, d, jax.random.split(key, STEPS))[0]

    data = jax.jit(jax.vmap(init))(jnp.arange(n))
    step = jax.jit(run)
    t0 = time.perf_counter()
    data = jax.block_until_ready(step(data, jax.random.key(2)))
    first = time.perf_counter() - t0
    rates = []
    for i in range(5):
        t0 = time.perf_counter()
        data = jax.block_until_ready(step(data, jax.random.key(3 + i)))
        rates.append(STEPS * n / (time.perf_counter() - t0))
    rate = statistics.median(rates)
    finite = np.isfinite(np.asarray(data.qpos)).all(axis=1).mean()
    height = np.median(np.asarray(data.qpos[:, 2]))
    return (
        f"{impl:5s} x{n:6d}: {rate:,.0f} physics steps/s = {rate / 5:,.0f} env steps/s, "
        f"first call {first:.1f} s, finite {finite:.3f}, median torso height {height:.3f} m"
    )


def main(argv: list[str] | None = None) -> None:
    p = argparse.ArgumentParser(description=(__doc__ or "").splitlines()[0])
    p.add_argument("--batches", nargs="+", type=int, default=[8192, 65536])
    p.add_argument("--impls", nargs="+", default=["jax", "warp"], choices=["jax", "warp"])
    args = p.parse_args(argv)
    print(f"# {jax.devices()[0].device_kind}, jax {jax.__version__}", flush=True)
    for n in args.batches:
        for impl in args.impls:
            try:
                print(measure(impl, n), flush=True)
            except Exception as err:  # a backend that is missing or refuses the model
                print(f"{impl:5s} x{n:6d}: failed: {type(err).__name__}: {err}", flush=True)


if __name__ == "__main__":
    main()
