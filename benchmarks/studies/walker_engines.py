"""What differs between MJX and MuJoCo's C engine for HexapodWalk-v0, without a policy.

Two measurements, each on a scripted open-loop tripod gait (so no trained policy is
needed), on the CPU (``JAX_PLATFORMS=cpu``):

* ``gait``: ``--envs`` envs walk the gait for ``--steps`` control steps from the task's
  start distribution; per engine variant: horizontal speed (m/s), mean body height (m),
  lowest uprightness (up axis z), envs that fell (the task's default termination).
* ``onestep``: states visited by the MJX gait rollout are stepped ONE control step by each
  variant; the table gives the RMS difference from MJX's step of the body's linear and
  angular velocity and of the joint velocities. Physics-param variants (foot friction
  x0.7, servo kp x0.8) put the engine gap beside the randomisation training already sees.

Variants: ``mjx`` (the task: float32, CG 6 iterations, 3 line-search steps), ``c`` (the
same model on MuJoCo C: float64, tolerance 1e-8, its own exact line search), ``c_conv``
and ``mjx_conv`` (both with 100 iterations / 50 line-search steps: the converged contact
solve), ``mjx_fric07`` and ``mjx_kp08`` (MJX with foot friction x0.7 or servo kp x0.8).

    JAX_PLATFORMS=cpu python benchmarks/studies/walker_engines.py --envs 16 --steps 200
"""

from __future__ import annotations

import argparse
import json
import math
import time
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from jaxenvs.robots.hexapod import quat_to_mat
from jaxenvs.tasks.hexapod import HexapodWalk, WalkConfig

CONVERGED = {"solver_iterations": 100, "ls_iterations": 50}
#: (physics, config overrides, params edit)
VARIANTS: dict[str, tuple[str, dict[str, Any], str | None]] = {
    "mjx": ("mjx", {}, None),
    "c": ("c", {}, None),
    "mjx_conv": ("mjx", CONVERGED, None),
    "c_conv": ("c", CONVERGED, None),
    "mjx_it12": ("mjx", {"solver_iterations": 12, "ls_iterations": 6}, None),
    "c_it12": ("c", {"solver_iterations": 12, "ls_iterations": 6}, None),
    "mjx_it24": ("mjx", {"solver_iterations": 24, "ls_iterations": 12}, None),
    "c_it24": ("c", {"solver_iterations": 24, "ls_iterations": 12}, None),
    "mjx_fric07": ("mjx", {}, "fric07"),
    "mjx_kp08": ("mjx", {}, "kp08"),
}
TRIPOD_A = np.array([1, 0, 1, 0, 1, 0], np.float32)  # lf, lr, rm swing together
SIDE = np.array([1, 1, 1, -1, -1, -1], np.float32)  # left legs, right legs


def gait_action(t: jax.Array, hz: float = 1.5) -> jax.Array:
    """A tripod gait's actions at control step ``t`` (0.05 s): hip swing, femur lift."""
    phase = 2 * math.pi * hz * 0.05 * t + jnp.where(TRIPOD_A > 0, 0.0, math.pi)
    hip = 0.5 * jnp.sin(phase) * SIDE
    femur = 0.35 * jnp.maximum(jnp.cos(phase), 0.0)
    tibia = -0.1 * jnp.ones(6)
    return jnp.stack([hip, femur, tibia], 1).reshape(18)


def make(variant: str) -> tuple[HexapodWalk, Any]:
    physics, overrides, edit = VARIANTS[variant]
    env = HexapodWalk(WalkConfig(physics=physics, **overrides))
    params = env.default_params
    model = dict(params.model)
    if edit == "fric07":
        model["pair_friction"] = model["pair_friction"] * 0.7
    elif edit == "kp08":
        model["actuator_gainprm"] = model["actuator_gainprm"].at[:, 0].multiply(0.8)
        model["actuator_biasprm"] = model["actuator_biasprm"].at[:, 1].multiply(0.8)
    return env, params.replace(model=model)


def gait(variant: str, envs: int, steps: int, seed: int) -> tuple[dict[str, Any], Any]:
    """Roll the gait out under ``variant``; its figures and the visited (qpos, qvel, warm)."""
    env, params = make(variant)

    @jax.jit
    def rollout(key: jax.Array) -> Any:
        state = jax.vmap(env.reset, (0, None))(jax.random.split(key, envs), params)
        start = state.data.qpos[:, :2]

        def body(carry, t):  # type: ignore[no-untyped-def]
            s, up = carry
            a = jnp.broadcast_to(gait_action(t), (envs, 18))
            visited = (s.data.qpos, s.data.qvel, s.data.qacc_warmstart)
            s = jax.vmap(env.step, (0, 0, None))(s, a, params)
            up = up & ~s.terminated
            upright = jax.vmap(quat_to_mat)(s.data.qpos[:, 3:7])[:, 2, 2]
            return (s, up), (s.data.qpos[:, 2], upright, up, visited)

        (s, up), (height, upright, ups, visited) = jax.lax.scan(
            body, (state, jnp.ones(envs, bool)), jnp.arange(steps)
        )
        moved = jnp.linalg.norm(s.data.qpos[:, :2] - start, axis=1)
        return moved, height, upright, up, visited

    t0 = time.perf_counter()
    moved, height, upright, up, visited = jax.device_get(rollout(jax.random.key(seed)))
    return {
        "speed_m_per_s": round(float(np.where(up, moved, np.nan).mean() / (steps * 0.05)), 4)
        if up.any()
        else None,
        "height_mean_m": round(float(height.mean()), 4),
        "upright_min": round(float(upright.min()), 4),
        "fell": int((~up).sum()),
        "wall_s": round(time.perf_counter() - t0, 1),
    }, visited


def onestep(
    variant: str, visited: Any, every: int, seed: int, ref: str = "mjx"
) -> dict[str, float]:
    """RMS difference of one control step from ``ref``'s step, from MJX-visited states."""
    qpos, qvel, warm = (np.asarray(x)[::every].reshape(-1, x.shape[-1]) for x in visited)
    t = np.repeat(np.arange(0, len(visited[0]), every), visited[0].shape[1])
    n = qpos.shape[0]
    out = {}
    for name in (ref, variant):
        env, params = make(name)

        @jax.jit
        def step(qpos, qvel, warm, t, env=env, params=params):  # type: ignore[no-untyped-def]
            s = jax.vmap(env.reset, (0, None))(jax.random.split(jax.random.key(seed), n), params)
            data = s.data.replace(qpos=qpos, qvel=qvel, qacc_warmstart=warm)
            s = s.replace(data=data)
            a = jax.vmap(gait_action)(t)
            return jax.vmap(env.step, (0, 0, None))(s, a, params).data.qvel

        out[name] = np.asarray(step(qpos, qvel, warm, t), np.float64)
    diff = out[variant] - out[ref]
    ok = np.isfinite(diff).all(1)

    def rms(cols: slice) -> float:
        return round(float(np.sqrt(np.mean(diff[ok][:, cols] ** 2))), 4)

    return {
        "lin_vel": rms(slice(0, 3)),
        "ang_vel": rms(slice(3, 6)),
        "joint_vel": rms(slice(6, 24)),
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=(__doc__ or "").splitlines()[0])
    parser.add_argument("--envs", type=int, default=16)
    parser.add_argument("--steps", type=int, default=200)
    parser.add_argument("--every", type=int, default=10, help="onestep: every n-th state")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument(
        "--pairs",
        nargs="*",
        default=[],
        metavar="A:B",
        help="onestep: also the difference between variants A and B",
    )
    parser.add_argument("--variants", nargs="+", default=list(VARIANTS), choices=list(VARIANTS))
    args = parser.parse_args()
    results: dict[str, Any] = {"envs": args.envs, "steps": args.steps, "gait": {}, "onestep": {}}
    visited = None
    for v in args.variants:
        results["gait"][v], vis = gait(v, args.envs, args.steps, args.seed)
        if v == "mjx":
            visited = vis
        print(v, results["gait"][v], flush=True)
    if visited is not None:
        for v in args.variants:
            if v != "mjx":
                results["onestep"][v] = onestep(v, visited, args.every, args.seed)
                print("onestep", v, results["onestep"][v], flush=True)
        for pair in args.pairs:
            a, b = pair.split(":")
            results["onestep"][pair] = onestep(b, visited, args.every, args.seed, ref=a)
            print("onestep", pair, results["onestep"][pair], flush=True)
    print(json.dumps(results, indent=1))


if __name__ == "__main__":
    main()
