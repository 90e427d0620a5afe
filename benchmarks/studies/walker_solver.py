"""HexapodWalk-v0's throughput under other solver settings, timed side by side.

Each variant is the shipped walker with some of: fewer, longer substeps (same 0.05 s
control period), another solver (CG or Newton) with other iteration counts, an elliptic
friction cone. Every variant is timed in the same interleaved rounds (``jaxenvs.bench``),
and checked for what a solver change can break: the stance under zero action (torso height
and joint speeds after 2 s) and divergence under random actions. Nothing here changes the
shipped task; it measures what a change would buy before anyone retrains the policy.

    python benchmarks/studies/walker_solver.py --batches 256 --steps 20 --variants base sub3 cg4
    python3 benchmarks/studies/walker_solver.py --batches 65536 262144    # on a GPU (Newton too)

Newton calls LAPACK's batched Cholesky, which deadlocks XLA's CPU thread pool at >= 128
envs on a 2-core machine (benchmarks/NOTES.md), so its variants refuse to run on CPU.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
from typing import Any

import jax
import jax.numpy as jnp
import mujoco
import numpy as np

import jaxenvs
from jaxenvs import bench
from jaxenvs.tasks import hexapod


@dataclasses.dataclass(frozen=True)
class Variant:
    substeps: int = 5
    solver: str = "CG"
    iterations: int = 6
    ls_iterations: int = 3
    cone: str = "pyramidal"

    @property
    def timestep(self) -> float:
        return 0.05 / self.substeps


VARIANTS = {
    "base": Variant(),
    "sub3": Variant(substeps=3),
    "cg4": Variant(iterations=4, ls_iterations=4),
    "sub3_cg4": Variant(substeps=3, iterations=4, ls_iterations=4),
    "elliptic": Variant(cone="elliptic"),
    "newton": Variant(solver="Newton", iterations=1, ls_iterations=4),
    "newton2": Variant(solver="Newton", iterations=2, ls_iterations=4),
    "sub3_newton": Variant(substeps=3, solver="Newton", iterations=1, ls_iterations=4),
}


def make_env(v: Variant, num_envs: int | None) -> Any:
    """The walker with ``v``'s settings (the task code itself is unchanged)."""
    solver = getattr(mujoco.mjtSolver, f"mjSOL_{v.solver.upper()}")
    cone = getattr(mujoco.mjtCone, f"mjCONE_{v.cone.upper()}")
    original = hexapod._solver_edit

    def solver_edit(iterations: int, ls_iterations: int):  # type: ignore[no-untyped-def]
        inner = original(iterations, ls_iterations)

        def edit(model: mujoco.MjModel) -> None:
            inner(model)
            model.opt.solver = solver
            model.opt.cone = cone

        return edit

    hexapod._solver_edit = solver_edit  # type: ignore[assignment]
    try:
        return jaxenvs.make(
            "HexapodWalk-v0",
            num_envs=num_envs,
            timestep=v.timestep,
            substeps=v.substeps,
            solver_iterations=v.iterations,
            ls_iterations=v.ls_iterations,
        )
    finally:
        hexapod._solver_edit = original  # type: ignore[assignment]


def stability(v: Variant, num_envs: int = 64, seconds: float = 2.0) -> dict[str, float]:
    """Stance under zero action (height, joint speed) and divergence under random actions."""
    benv = make_env(v, num_envs)
    env = benv.env
    n_steps = round(seconds / 0.05)
    zero = jnp.zeros((num_envs, *env.action_shape), jnp.float32)

    @jax.jit
    def stand(key: jax.Array) -> Any:
        s = benv.reset(key)
        s, _ = jax.lax.scan(lambda s, _: (benv.step(s, zero), None), s, None, length=n_steps)
        return s

    @jax.jit
    def shake(key: jax.Array) -> jax.Array:
        s = benv.reset(key)

        def body(s: Any, k: jax.Array) -> tuple[Any, jax.Array]:
            a = jax.random.uniform(k, (num_envs, *env.action_shape), minval=-1.0, maxval=1.0)
            s = benv.step(s, a)
            return s, s.info["diverged"]

        _, div = jax.lax.scan(body, s, jax.random.split(key, 200))
        return div

    s = stand(jax.random.key(1))
    height = np.asarray(s.data.xpos[:, env._torso, 2])
    joint_speed = np.abs(np.asarray(s.data.qvel[:, 6:])).max(axis=1)
    div = np.asarray(shake(jax.random.key(2)))
    return {
        "stance_height_m": float(np.median(height)),
        "stance_max_joint_speed": float(np.max(joint_speed)),
        "random_diverged_per_1000_steps": float(div.sum() / div.size * 1000),
    }


def main(argv: list[str] | None = None) -> None:
    p = argparse.ArgumentParser(description=(__doc__ or "").splitlines()[0])
    p.add_argument("--variants", nargs="+", default=list(VARIANTS), choices=list(VARIANTS))
    p.add_argument("--batches", nargs="+", type=int, default=[256])
    p.add_argument("--steps", type=int, default=20)
    p.add_argument("--repeats", type=int, default=3)
    p.add_argument("--no-stability", action="store_true")
    p.add_argument("--json", default=None)
    args = p.parse_args(argv)
    info = bench.machine()
    print(f"# {info['host']} {info['device']} jax {info['jax']}", flush=True)
    on_cpu = jax.default_backend() == "cpu"
    names = [n for n in args.variants if not (on_cpu and VARIANTS[n].solver == "Newton")]
    for n in set(args.variants) - set(names):
        print(f"# {n}: skipped on CPU (Newton's LAPACK Cholesky deadlocks XLA's CPU pool)")
    stable = {}
    if not args.no_stability:
        for n in names:
            stable[n] = stability(VARIANTS[n])
            print(n, dataclasses.asdict(VARIANTS[n]), stable[n], flush=True)
    results = []
    for b in args.batches:
        runners = []
        for n in names:
            benv = make_env(VARIANTS[n], b)
            runners.append(bench.prepare_batched(benv, "HexapodWalk-v0", "full", args.steps, n))
            print(f"# compiled {n} x{b}: {runners[-1].info['first_call_s']:.1f} s", flush=True)
        results += bench.time_runners(runners, args.repeats)
    rows: list[list[Any]] = [["variant", "envs", "env steps/s", "first call s", "vs base"]]
    for r in results:
        base = next(
            (x for x in results if x["variant"] == "base" and x["num_envs"] == r["num_envs"]), None
        )
        ratio = r["env_steps_per_s"] / base["env_steps_per_s"] if base else float("nan")
        rows.append(
            [
                r["variant"],
                r["num_envs"],
                f"{r['env_steps_per_s']:,.0f}",
                f"{r['first_call_s']:.1f}",
                f"{ratio:.2f}x",
            ]
        )
    print(bench.format_table(rows))
    if args.json:
        with open(args.json, "w") as f:
            json.dump({"machine": info, "stability": stable, "results": results}, f, indent=2)


if __name__ == "__main__":
    main()
