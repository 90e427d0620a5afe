"""The peers, timed beside our envs, and the CPU targets of the throughput issue.

The harness: Gymnasium (one env, SyncVectorEnv), EnvPool, MuJoCo's C ``rollout`` on our
own MJCF at our substeps, and gymnax's closed-form CartPole, each prepared as a
:class:`jaxenvs.bench.Runner` filed under the task of ours it compares to, so
:func:`jaxenvs.bench.time_runners` times it in the same interleaved rounds. Every peer is an
optional import (``pip install -e '.[bench]'``); one that is missing, or breaks while
warming up, is returned as a :class:`Skipped` with the reason, never dropped. The harness
is not part of the package: ``jaxenvs bench --peers`` loads this file from the source
checkout it runs in.

Run as a script: for every task that has peers (CartPole-v0, Reacher-v0, HexapodWalk-v0
where registered), our batched env over a batch sweep, then its peers, all timed in the
same interleaved rounds (medians); peers that are not installed are listed as skipped.
Ends with the targets, met or missed.

    python benchmarks/peers.py --batches 256 2048 16384 --json peers_cpu2_cartpole_reacher
"""

from __future__ import annotations

import argparse
import dataclasses
import os
from collections.abc import Callable, Sequence
from typing import Any

import jax
import numpy as np

import jaxenvs
from jaxenvs import bench
from jaxenvs.bench import Runner, best_of, is_ours
from jaxenvs.core import Env

#: peers of each of our tasks: (Gymnasium id, EnvPool id).
PEER_IDS: dict[str, tuple[str, str]] = {
    "CartPole-v0": ("CartPole-v1", "CartPole-v1"),
    "Reacher-v0": ("Reacher-v5", "Reacher-v4"),
    "HexapodWalk-v0": ("Ant-v5", "Ant-v4"),
}


@dataclasses.dataclass(frozen=True)
class Skipped:
    """A peer that could not run here, and why."""

    name: str
    task: str
    variant: str
    reason: str

    def as_dict(self) -> dict[str, Any]:
        return {**dataclasses.asdict(self), "skipped": True}


def _why(err: Exception) -> str:
    if isinstance(err, ImportError):
        return f"not installed (pip install -e '.[bench]'): {err}"
    return f"{type(err).__name__}: {err}"


def _rng() -> np.random.Generator:
    return np.random.default_rng(0)


def _gymnasium_single(task: str, gym_id: str) -> Runner | Skipped:
    try:
        import gymnasium

        env = gymnasium.make(gym_id)
    except Exception as err:  # missing mujoco bindings, unknown id, ...
        return Skipped("gymnasium", task, gym_id, _why(err))
    env.action_space.seed(0)
    env.reset(seed=0)
    actions = [env.action_space.sample() for _ in range(256)]
    chunk = 200

    def unit() -> int:
        for i in range(chunk):
            _, _, term, trunc, _ = env.step(actions[i % 256])
            if term or trunc:
                env.reset()
        return chunk

    return Runner("gymnasium", task, gym_id, 1, unit, {"threads": 1})


def _gymnasium_sync(task: str, gym_id: str, num_envs: int) -> Runner | Skipped:
    try:
        import gymnasium

        venv = gymnasium.vector.SyncVectorEnv([lambda: gymnasium.make(gym_id)] * num_envs)
    except Exception as err:
        return Skipped("gymnasium SyncVectorEnv", task, gym_id, _why(err))
    venv.action_space.seed(0)
    venv.reset(seed=0)
    actions = [venv.action_space.sample() for _ in range(64)]
    chunk = 20

    def unit() -> int:
        for i in range(chunk):
            venv.step(actions[i % 64])
        return chunk * num_envs

    return Runner("gymnasium SyncVectorEnv", task, gym_id, num_envs, unit, {"threads": 1})


def _envpool(task: str, pool_id: str, num_envs: int, threads: int) -> Runner | Skipped:
    try:
        import envpool

        env = envpool.make(
            pool_id,
            env_type="gymnasium",
            num_envs=num_envs,
            batch_size=num_envs,
            num_threads=threads,
            seed=0,
        )
    except Exception as err:
        return Skipped("envpool", task, pool_id, _why(err))
    env.reset()
    space = env.action_space
    rng = _rng()
    if hasattr(space, "n"):
        actions = rng.integers(0, space.n, (16, num_envs))
    else:
        lo, hi = space.low, space.high
        actions = rng.uniform(lo, hi, (16, num_envs, *space.shape)).astype(space.dtype)

    def unit() -> int:
        for a in actions:
            env.step(a)
        return len(actions) * num_envs

    return Runner("envpool", task, pool_id, num_envs, unit, {"threads": threads})


def _gymnax(task: str, num_envs: int, steps: int) -> Runner | Skipped:
    try:
        import gymnax

        env, params = gymnax.make("CartPole-v1")
    except Exception as err:
        return Skipped("gymnax", task, "CartPole-v1", _why(err))
    reset = jax.vmap(env.reset, in_axes=(0, None))
    vstep = jax.vmap(env.step, in_axes=(0, 0, 0, None))

    def run(carry: Any, key: jax.Array) -> Any:
        def body(c: Any, k: jax.Array) -> tuple[Any, None]:
            state, _ = c
            ks, ka = jax.random.split(k)
            act = jax.random.randint(ka, (num_envs,), 0, 2)
            out = vstep(jax.random.split(ks, num_envs), state, act, params)
            return (out[1], out[0]), None

        carry, _ = jax.lax.scan(body, carry, jax.random.split(key, steps))
        return carry

    fn = jax.jit(run, donate_argnums=0)  # as gymnax's users compile it
    obs, state = reset(jax.random.split(jax.random.key(0), num_envs), params)
    keys = iter(jax.random.split(jax.random.key(1), 1_000_000))
    holder = [jax.block_until_ready(fn((state, obs), next(keys)))]

    def unit() -> int:
        holder[0] = jax.block_until_ready(fn(holder[0], next(keys)))
        return num_envs * steps

    return Runner("gymnax", task, "CartPole-v1", num_envs, unit, {"note": "closed form, no MuJoCo"})


def _mujoco_rollout(task: str, env: Env, num_envs: int, threads: int) -> Runner | Skipped:
    try:
        import mujoco
        from mujoco import rollout
    except Exception as err:
        return Skipped("mujoco.rollout", task, "our MJCF", _why(err))
    # the model our MJX step runs (the MJCF without cameras, lights and non-colliding
    # geoms: jaxenvs.physics.sim.physics_model), so both sides do the same physics work
    model = getattr(env.sim, "physics_mj_model", env.sim.mj_model)
    substeps = env.sim.substeps
    data = mujoco.MjData(model)
    if model.nkey > 0:
        mujoco.mj_resetDataKeyframe(model, data, 0)
    mujoco.mj_forward(model, data)
    spec = mujoco.mjtState.mjSTATE_FULLPHYSICS
    x0 = np.empty(mujoco.mj_stateSize(model, spec))
    mujoco.mj_getState(model, data, x0, spec)
    env_steps = max(1, 200 // substeps)
    nstep = env_steps * substeps
    lo, hi = model.actuator_ctrlrange[:, 0], model.actuator_ctrlrange[:, 1]
    ctrl = _rng().uniform(lo, hi, (num_envs, env_steps, model.nu))
    ctrl = np.repeat(ctrl, substeps, axis=1)
    x0s = np.tile(x0, (num_envs, 1))
    datas = [mujoco.MjData(model) for _ in range(threads)]
    out = np.empty((num_envs, nstep, x0.size))
    sens = np.empty((num_envs, nstep, model.nsensordata))

    def unit() -> int:
        rollout.rollout(model, datas, x0s, ctrl, nstep=nstep, state=out, sensordata=sens)
        return num_envs * env_steps

    info = {"threads": threads, "substeps": substeps, "timestep": model.opt.timestep}
    return Runner("mujoco.rollout", task, "our MJCF", num_envs, unit, info)


def peer_runners(
    task: str,
    num_envs: int = 256,
    gymnax_envs: int = 16384,
    threads: int | None = None,
    sync_envs: int = 16,
    names: Sequence[str] | None = None,
) -> list[Runner | Skipped]:
    """Every peer of ``task`` (or those whose name is in ``names``), prepared; missing
    ones as :class:`Skipped`.

    All tasks get MuJoCo's C rollout on our own MJCF at our substeps (``threads`` threads,
    default all cores); tasks with a Gymnasium/EnvPool counterpart (:data:`PEER_IDS`) get
    those too (one env and a ``sync_envs`` SyncVectorEnv; EnvPool at ``num_envs`` envs);
    ``CartPole-v0`` also gets gymnax's closed-form CartPole at ``gymnax_envs`` envs.
    """
    threads = threads or os.cpu_count() or 1
    env = jaxenvs.make(task)
    assert isinstance(env, Env)
    makers: list[tuple[str, str, Callable[[], Runner | Skipped]]] = []
    if task in PEER_IDS:
        gym_id, pool_id = PEER_IDS[task]
        makers += [
            ("gymnasium", gym_id, lambda: _gymnasium_single(task, gym_id)),
            ("gymnasium SyncVectorEnv", gym_id, lambda: _gymnasium_sync(task, gym_id, sync_envs)),
            ("envpool", pool_id, lambda: _envpool(task, pool_id, num_envs, threads)),
        ]
    makers.append(
        ("mujoco.rollout", "our MJCF", lambda: _mujoco_rollout(task, env, num_envs, threads))
    )
    if task == "CartPole-v0":
        makers.append(("gymnax", "CartPole-v1", lambda: _gymnax(task, gymnax_envs, 100)))
    out: list[Runner | Skipped] = []
    for name, variant, make in makers:
        if names is not None and name not in names:
            continue
        try:
            out.append(make())
        except Exception as err:  # a peer that breaks while warming up is reported, not fatal
            out.append(Skipped(name, task, variant, _why(err)))
    return out


def ratios(results: Sequence[dict[str, Any]]) -> list[dict[str, Any]]:
    """Ours (best batch, full step, each engine measured) / each peer of the same task."""
    engines = sorted({r.get("physics", "mjx") for r in results if is_ours(r)})
    rows = []
    for peer in results:
        if is_ours(peer) or peer.get("skipped"):
            continue
        for physics in engines:
            best = best_of(results, peer["task"], physics=physics)
            if best is None:
                continue
            rows.append(
                {
                    "task": peer["task"],
                    "physics": physics,
                    "our_envs": best["num_envs"],
                    "ours": best["env_steps_per_s"],
                    "peer": f"{peer['name']} {peer['variant']} x{peer['num_envs']}",
                    "peer_steps_per_s": peer["env_steps_per_s"],
                    "ratio": best["env_steps_per_s"] / peer["env_steps_per_s"],
                }
            )
    return rows


#: CPU targets: task -> (peer name, peer variant, minimum ratio ours / peer).
TARGETS = (
    ("CartPole-v0", "envpool", "CartPole-v1", 2.5),
    ("Reacher-v0", "envpool", "Reacher-v4", 10.0),
    ("HexapodWalk-v0", "envpool", "Ant-v4", 2.0),
)
FIRST_CALL_S = 20.0


def verdicts(results: list[dict[str, Any]]) -> list[list[Any]]:
    """One row per target: the measured figure, the bar, met or missed."""
    rows: list[list[Any]] = [["task", "target", "measured", "verdict"]]
    for task, name, variant, bar in TARGETS:
        best = bench.best_of(results, task)
        peer = next(
            (
                r
                for r in results
                if r["task"] == task and r["name"] == name and not r.get("skipped")
            ),
            None,
        )
        if best is None or peer is None:
            rows.append([task, f">= {bar}x {name} {variant}", "not measured", "-"])
            continue
        ratio = best["env_steps_per_s"] / peer["env_steps_per_s"]
        rows.append([task, f">= {bar}x {name} {variant}", f"{ratio:.2f}x", _verdict(ratio >= bar)])
    for task in sorted({r["task"] for r in results if r["name"] == "jaxenvs"}):
        ours = [r for r in results if r["task"] == task and r["name"] == "jaxenvs"]
        first = max(r["first_call_s"] for r in ours)
        rows.append(
            [
                task,
                f"first call <= {FIRST_CALL_S:.0f} s",
                f"{first:.1f} s (worst)",
                _verdict(first <= FIRST_CALL_S),
            ]
        )
        rollout = next(
            (
                r
                for r in results
                if r["task"] == task and r["name"] == "mujoco.rollout" and not r.get("skipped")
            ),
            None,
        )
        best = bench.best_of(results, task)
        if rollout is not None and best is not None:
            ratio = best["env_steps_per_s"] / rollout["env_steps_per_s"]
            rows.append([task, ">= 1x mujoco.rollout", f"{ratio:.2f}x", _verdict(ratio >= 1.0)])
    return rows


def _verdict(ok: bool) -> str:
    return "met" if ok else "MISSED"


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=(__doc__ or "").splitlines()[0])
    parser.add_argument("--tasks", nargs="+", default=None)
    parser.add_argument("--batches", nargs="+", type=int, default=[256, 2048, 16384])
    parser.add_argument("--steps", type=int, default=100)
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--peer-envs", type=int, default=256)
    parser.add_argument("--json", default=None, help="NAME: benchmarks/results/NAME.json")
    args = parser.parse_args(argv)
    # imported here: `jaxenvs bench --peers` loads this file without benchmarks/ on the path
    import results_io

    ids = jaxenvs.list_envs()
    tasks = args.tasks or [t for t, *_ in TARGETS if t in ids]
    runners: list[bench.Runner] = []
    skipped = []
    for task in tasks:
        for b in args.batches:
            print(f"# compiling {task} x{b}", flush=True)
            runners.append(bench.prepare_ours(task, b, "full", args.steps))
        for p in peer_runners(task, args.peer_envs, max(args.batches)):
            if isinstance(p, bench.Runner):
                runners.append(p)
            else:
                skipped.append(p.as_dict())
    results = bench.time_runners(runners, args.repeats, log=lambda m: print(f"# {m}"))
    results += skipped
    rows: list[list[Any]] = [["task", "who", "variant", "envs", "env steps/s"]]
    for r in results:
        sps = "skipped: " + r["reason"] if r.get("skipped") else f"{r['env_steps_per_s']:,.0f}"
        rows.append([r["task"], r["name"], r["variant"], r.get("num_envs", "-"), sps])
    print(bench.format_table(rows))
    print()
    table = verdicts(results)
    print(bench.format_table(table))
    if args.json:
        title = f"{', '.join(tasks)} beside the peers"
        extra = {"bench_machine": bench.machine(), "targets": table}
        results_io.write(args.json, results_io.record(args.json, title, results, extra=extra))


if __name__ == "__main__":
    main()
