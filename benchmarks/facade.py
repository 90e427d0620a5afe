"""Steps/s of the Gymnasium facade next to Gymnasium's own env of the same kind.

Single env: ``gymnasium.make("jaxenvs/ID")`` (with the wrappers ``make`` adds) and the raw
``JaxEnv``, against ``gymnasium.make(PEER)``, as shipped (MuJoCo's Python bindings time every
step's stages) and with MuJoCo's timers off, as our native engine leaves them. Vector:
``gymnasium.make_vec("jaxenvs/ID", N, "vector_entry_point")`` (auto-reset NEXT_STEP, the
default, and SAME_STEP) against
``gymnasium.make_vec(PEER, N, "sync")`` (``SyncVectorEnv``), the same two ways. Random
actions, drawn before timing; episodes end and reset as they do in use. Rounds alternate
ours and the peer so that machine noise hits both alike; the best round is reported (and
all rounds in the JSON).

    python benchmarks/facade.py --tasks CartPole-v0 Reacher-v0 --num-envs 1024 \\
        --json facade_cpu2_cartpole_reacher
"""

from __future__ import annotations

import argparse
import functools
import statistics
import time
from collections.abc import Callable
from typing import Any

import gymnasium as gym
import mujoco
import results_io

import jaxenvs  # noqa: F401  (registers jaxenvs/<id>)
from jaxenvs.physics import native

PEERS = {"CartPole-v0": "CartPole-v1", "Reacher-v0": "Reacher-v5"}
#: the suffix of the vector env's row in auto-reset mode SAME_STEP (NEXT_STEP is the default)
SAME_STEP = "SAME_STEP"
#: what is timed: the one env (``gym.make``) and the vector env (``gym.make_vec``)
MODES = ("single", "vector")


def _actions(space: gym.Space, count: int, seed: int) -> list[Any]:
    space.seed(seed)
    return [space.sample() for _ in range(count)]


def time_single(env: gym.Env, steps: int, seed: int = 0) -> float:
    """Steps/s of one env over ``steps`` steps (after a warm-up step)."""
    actions = _actions(env.action_space, 256, seed)
    env.reset(seed=seed)
    env.step(actions[0])
    start = time.perf_counter()
    for t in range(steps):
        _, _, terminated, truncated, _ = env.step(actions[t % 256])
        if terminated or truncated:
            env.reset()
    return steps / (time.perf_counter() - start)


def time_vector(envs: gym.vector.VectorEnv, steps: int, seed: int = 0) -> float:
    """Env steps/s (num_envs x vector steps / s) of a vector env (after a warm-up step)."""
    actions = _actions(envs.action_space, 16, seed)
    envs.reset(seed=seed)
    envs.step(actions[0])
    start = time.perf_counter()
    for t in range(steps):
        envs.step(actions[t % 16])
    return steps * envs.num_envs / (time.perf_counter() - start)


def _peer_clock(off: bool) -> None:
    """MuJoCo's stage clock for a peer's round: as a user of the peer has it (the Python
    bindings' default clock, which times every step's stages) or off, as our native engine
    leaves it in this process (docs/engines.md, "MuJoCo's stage timers")."""
    if off:
        lib = native.library()
        assert lib is not None
        lib.jaxenvs_set_clock(None)
    else:
        mujoco.set_mjcb_time(None)  # the bindings' default clock


def _with_clock(off: bool, fn: Callable[[], float]) -> Callable[[], float]:
    """``fn`` timed with MuJoCo's clock set as :func:`_peer_clock` sets it."""

    def timed() -> float:
        _peer_clock(off)
        return fn()

    return timed


def _rounds(fns: dict[str, Callable[[], float]], rounds: int) -> dict[str, list[float]]:
    out: dict[str, list[float]] = {k: [] for k in fns}
    for _ in range(rounds):
        for name, fn in fns.items():
            out[name].append(fn())
    return out


def bench_task(
    env_id: str,
    steps: int,
    num_envs: int,
    vec_steps: int,
    peer_vec_steps: int,
    rounds: int,
    modes: tuple[str, ...] = MODES,
) -> dict[str, Any]:
    peer = PEERS.get(env_id)
    timed: dict[str, dict[str, Callable[[], float]]] = {}
    first: dict[str, float] = {}
    closing: list[Any] = []
    if "single" in modes:
        t0 = time.perf_counter()
        ours = gym.make(f"jaxenvs/{env_id}")
        raw = gym.make(f"jaxenvs/{env_id}").unwrapped
        time_single(ours, 2)
        first["single"] = time.perf_counter() - t0
        timed["single"] = {
            "ours (gym.make)": lambda: time_single(ours, steps),
            "ours (raw JaxEnv)": lambda: time_single(raw, steps),
        }
        closing += [ours, raw]
    if "vector" in modes:
        t0 = time.perf_counter()
        ours_vec = gym.make_vec(
            f"jaxenvs/{env_id}", num_envs, vectorization_mode="vector_entry_point"
        )
        time_vector(ours_vec, 1)
        first["vector"] = time.perf_counter() - t0
        t0 = time.perf_counter()
        same_vec = gym.make_vec(
            f"jaxenvs/{env_id}", num_envs, "vector_entry_point", autoreset_mode="same_step"
        )
        time_vector(same_vec, 1)
        first["same_step"] = time.perf_counter() - t0
        timed["vector"] = {
            f"ours make_vec x{num_envs}": lambda: time_vector(ours_vec, vec_steps),
            f"ours make_vec x{num_envs}, {SAME_STEP}": lambda: time_vector(same_vec, vec_steps),
        }
        closing += [ours_vec, same_vec]
    if peer is not None:
        clocks = [(False, "")] + ([(True, ", MuJoCo timers off")] if native.available() else [])
        if "single" in modes:
            one = functools.partial(time_single, gym.make(peer), steps)
            for off, suffix in clocks:
                timed["single"][f"Gymnasium {peer}{suffix}"] = _with_clock(off, one)
        if "vector" in modes:
            peer_vec = gym.make_vec(peer, num_envs, vectorization_mode="sync")
            many = functools.partial(time_vector, peer_vec, peer_vec_steps)
            for off, suffix in clocks:
                name = f"Gymnasium {peer} SyncVectorEnv x{num_envs}{suffix}"
                timed["vector"][name] = _with_clock(off, many)
    result: dict[str, Any] = {"task": env_id, "peer": peer, "num_envs": num_envs}
    result["first_call_s"] = first
    for mode, fns in timed.items():
        result[mode] = _rounds(fns, rounds)
    for env in closing:
        env.close()
    return result


def report(result: dict[str, Any]) -> None:
    kinds = [k for k in MODES if k in result]
    rounds = len(next(iter(result[kinds[0]].values())))
    print(f"\n{result['task']} (peer {result['peer']}), best of {rounds} rounds")
    for kind in kinds:
        best = {name: max(v) for name, v in result[kind].items()}
        median = {name: statistics.median(v) for name, v in result[kind].items()}
        for name, value in best.items():
            print(f"  {kind:6s}  {name:45s} {value:12,.0f} steps/s (median {median[name]:,.0f})")
        names = list(best)
        for peer in (n for n in names if not n.startswith("ours")):
            print(
                f"  {kind:6s}  ours/{peer}: {best[names[0]] / best[peer]:.2f}x "
                f"(medians {median[names[0]] / median[peer]:.2f}x)"
            )
    calls = ", ".join(f"{k} {v:.1f} s" for k, v in result["first_call_s"].items())
    print(f"  first call (compile): {calls}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--tasks", nargs="+", default=list(PEERS))
    parser.add_argument("--steps", type=int, default=3000, help="single-env steps per round")
    parser.add_argument("--num-envs", type=int, default=1024)
    parser.add_argument("--vec-steps", type=int, default=200, help="our vector steps per round")
    parser.add_argument("--peer-vec-steps", type=int, default=10, help="SyncVectorEnv steps")
    parser.add_argument("--rounds", type=int, default=3)
    parser.add_argument(
        "--modes", nargs="+", choices=MODES, default=list(MODES), help="one env, vector env"
    )
    parser.add_argument("--json", help=results_io.HELP)
    args = parser.parse_args()
    results = []
    for env_id in args.tasks:
        res = bench_task(
            env_id,
            args.steps,
            args.num_envs,
            args.vec_steps,
            args.peer_vec_steps,
            args.rounds,
            tuple(args.modes),
        )
        report(res)
        results.append(res)
    if args.json:
        title = f"the Gymnasium facade on {', '.join(args.tasks)} against Gymnasium's envs"
        results_io.write(args.json, results_io.record(args.json, title, rows(results)))


def rows(results: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """One flat row per task, mode and contender, with the steps/s of every round."""
    out = []
    for r in results:
        for mode in (m for m in MODES if m in r):
            for who, rounds in r[mode].items():
                ours = who.startswith("ours")
                first = "same_step" if who.endswith(SAME_STEP) else mode
                out.append(
                    {
                        "task": r["task"],
                        "peer": r["peer"],
                        "mode": mode,
                        "who": who,
                        "num_envs": 1 if mode == "single" else r["num_envs"],
                        "steps_per_s_rounds": rounds,
                        "first_call_s": r["first_call_s"][first] if ours else None,
                    }
                )
    return out


if __name__ == "__main__":
    main()
