"""HexapodJoystickRough-v0 and HexapodWalkRough-v0 policies per seed: greedy tracking (the
joystick) or walking between targets (the walker) and falls at the middle and the top level
of the terrain, under MJX and MuJoCo C, and a table of the seeds.

One seed on one GPU (a cold compile cache: the run compiles everything it runs), then its
evaluation under MJX on that GPU and under MuJoCo C on the CPU::

    jaxenvs train HexapodJoystickRough-v0 --algo ppo --no-video --no-compile-cache \\
        --seed 0 --out runs/rough_s0
    python benchmarks/rough_seeds.py eval runs/rough_s0
    JAX_PLATFORMS=cpu python benchmarks/rough_seeds.py eval runs/rough_s0 --physics c
    python benchmarks/rough_seeds.py table runs/rough_s0 runs/rough_s1 runs/rough_s2 \\
        --json ppo_joystick_rough_seeds_h100

``eval`` drives the run's greedy policy in one batch of envs, each for one episode of
``--seconds`` (20 s) with the command redrawn on the task's schedule over the run's full
command ranges, pushes and action noise off, the run's observation noise and filter kept,
the curriculum off (each env stays on its tile), and the task's DEFAULT fall rule (the
body below 0.06 m above the ground under it, or tilted more than ~45 degrees), whatever
the run trained with. Groups: ``mid`` (every env at the middle level, ``levels // 2``)
and ``top`` (the top level), env ``i`` of a group on terrain type ``i mod types`` (every
type equally), each under the task's default physics params (``default``) and under
params drawn by ``env.sample_params``, one draw per env (``randomized``). Per group and
per type: ``fell_fraction`` (envs that fell in the episode), ``tracking_error_lin`` (RMS
over the env-steps while up of |command - velocity| in the horizontal plane, m/s, the
body's mean velocity over the control step in its heading frame) and
``tracking_error_yaw`` (the same of the yaw rate, rad/s). For the walker, instead of the
tracking errors: ``speed`` (the mean over the env-steps while up of the progress toward the
target in force, m/s) and ``targets_per_minute`` (targets reached while up, per env and
minute of the episode). It writes ``RUN/rough_eval_<physics>.json`` (with
``--hfield-contact mujoco`` under MuJoCo C: ``RUN/rough_eval_c_mujoco.json``, the table's
``mujoco_c_prisms``; the C evals before that option existed used MuJoCo's collider).

``table`` collects the eval files, each run's summary.json, progress.csv and config.yaml
into one row per run: ``seed``, ``train_seconds`` (the run's wall, compile included),
``final_mean_level`` (progress.csv's ``level`` of the last chunk: the mean over the
training envs), ``first_chunk_mean_level`` (the same of the first chunk), ``levels``,
``chunks`` of ``num_chunks`` trained and ``finished`` (False for a run stopped early),
and for ``mjx``, ``mjx_randomized``, ``mujoco_c``, ``mujoco_c_randomized`` and (where
that eval exists) ``mujoco_c_prisms`` a dict with ``mid`` and ``top``, each holding the
task's figures (``fell_fraction`` and the tracking errors, or the walker's ``speed`` and
``targets_per_minute``) and
``mid_fell_by_type`` (each terrain type's ``fell_fraction`` at the middle level), and
``mid_by_type`` and ``top_by_type`` (each type's figures at that level). The runs
of one table are of one task.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import math
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
import results_io

from jaxenvs.core import BatchedEnv
from jaxenvs.run import runner
from jaxenvs.scenes import HFIELD_CONTACTS
from jaxenvs.tasks.hexapod.rough import RoughCarry, TerrainTask

#: each task's figures, and the per-step ``info`` each reads (module docstring)
FIGURES = {
    "HexapodJoystickRough-v0": ("fell_fraction", "tracking_error_lin", "tracking_error_yaw"),
    "HexapodWalkRough-v0": ("fell_fraction", "speed", "targets_per_minute"),
}
STEP_INFO = {
    "HexapodJoystickRough-v0": {"lin": "lin_error", "yaw": "yaw_error"},
    "HexapodWalkRough-v0": {"progress": "progress", "targets": "targets_reached"},
}
#: (record field, eval, params group) of each bench in a ``table`` row; the eval ``c_mujoco``
#: is MuJoCo C with MuJoCo's own heightfield collider (``--hfield-contact mujoco``)
BENCHES = (
    ("mjx", "mjx", "default"),
    ("mjx_randomized", "mjx", "randomized"),
    ("mujoco_c", "c", "default"),
    ("mujoco_c_randomized", "c", "randomized"),
    ("mujoco_c_prisms", "c_mujoco", "default"),
)


def eval_env(
    run_dir: str,
    physics: str | None,
    max_contacts: int | None = None,
    hfield_contact: str | None = None,
) -> tuple[str, TerrainTask, Any]:
    """The run's id, its env as ``eval`` measures it (module docstring; with MJX's contact
    budget ``max_contacts`` and MuJoCo C's ``hfield_contact`` instead of the run's, if
    given) and its greedy policy."""
    env_id, env, act = runner.load_policy(run_dir, physics)
    if env_id not in FIGURES or not isinstance(env, TerrainTask):
        raise SystemExit(f"{run_dir} is a run of {env_id}, not of {' or '.join(FIGURES)}")
    default = type(env.config)()
    off = {"push_probability": 0.0} if hasattr(default, "push_probability") else {}
    config = dataclasses.replace(
        env.config,
        min_height=default.min_height,
        min_upright=default.min_upright,
        action_noise=0.0,
        curriculum=False,
        **off,
        **({} if max_contacts is None else {"max_contacts": max_contacts}),
        **({} if hfield_contact is None else {"hfield_contact": hfield_contact}),
    )
    return env_id, type(env)(config), act


#: the evaluation's groups of envs, ``(params, level)``, in the order of :func:`tiles`
GROUPS = tuple((p, lv) for p in ("default", "randomized") for lv in ("mid", "top"))


def with_episode(env: TerrainTask, seconds: float) -> tuple[TerrainTask, int]:
    """``env`` with an episode longer than ``seconds`` (no time limit inside them) and
    the number of control steps ``seconds`` make."""
    steps = round(seconds / env.control_dt)
    if steps >= env.config.episode_length:
        env = type(env)(dataclasses.replace(env.config, episode_length=steps + 1))
    return env, steps


def groups(out: dict[str, Any], n: int) -> Iterator[tuple[str, str, dict[str, np.ndarray]]]:
    """Each of :data:`GROUPS` with its ``(steps, n)`` arrays of :func:`rollout`'s
    ``out``."""
    for g, (params, level) in enumerate(GROUPS):
        yield params, level, {k: np.asarray(v)[:, g * n : (g + 1) * n] for k, v in out.items()}


def tiles(env: TerrainTask, n: int) -> RoughCarry:
    """The carries of the four groups of ``n`` envs, in the order default mid, default
    top, randomized mid, randomized top; env ``i`` of a group on column ``i mod types``."""
    c = env.config
    levels = np.repeat([c.levels // 2, c.levels - 1] * 2, n)
    columns = np.tile(np.arange(n) % len(c.terrain_types), 4)
    return RoughCarry(level=jnp.asarray(levels, jnp.int32), column=jnp.asarray(columns, jnp.int32))


def rollout(
    env: TerrainTask, act: Any, reads: dict[str, str], n: int, steps: int, seed: int
) -> dict[str, Any]:
    """:func:`trajectories` of the four groups of :func:`tiles`: ``(steps, 4 n)`` arrays."""
    carry = tiles(env, n)
    keys = jax.random.split(jax.random.key(seed), 4 * n)
    split = (slice(0, 2 * n), slice(2 * n, 4 * n))
    plain = BatchedEnv(env, 2 * n, devices=1).fresh_starts(
        keys[split[0]], None, jax.tree.map(lambda x: x[split[0]], carry)
    )
    drawn = BatchedEnv(env, 2 * n, randomize=True, devices=1).fresh_starts(
        keys[split[1]], None, jax.tree.map(lambda x: x[split[1]], carry)
    )
    default = jax.tree.map(lambda x: jnp.broadcast_to(x, (2 * n, *x.shape)), env.default_params)
    params = jax.tree.map(lambda *xs: jnp.concatenate(xs), default, drawn.params)
    state = jax.tree.map(lambda *xs: jnp.concatenate(xs), plain, drawn.replace(params=None))
    return trajectories(env, act, reads, state, params, steps)


def trajectories(
    env: Any, act: Any, reads: dict[str, str], state: Any, params: Any, steps: int
) -> dict[str, Any]:
    """Each env's per-step ``info`` entries named by ``reads`` (output name: info key) and
    whether it was up before and after each step (``(steps, envs)`` arrays), the greedy
    policy ``act`` driving the batch ``state`` under the batched ``params`` (no reset: a
    fallen env stays fallen)."""
    n = state.obs.shape[0]

    def body(carry: Any, _: None) -> tuple[Any, dict[str, jax.Array]]:
        s, up = carry
        a = jax.vmap(act)(s.obs, jax.random.split(s.key[0], n))
        nxt = jax.vmap(env.step)(s, a, params)
        after = up & ~nxt.terminated
        out = {name: nxt.info[key] for name, key in reads.items()} | {"up": up}
        return (nxt, after), out | {"after": after}

    run = jax.jit(lambda s: jax.lax.scan(body, (s, jnp.ones(n, bool)), None, length=steps))
    return jax.device_get(run(state)[1])


def figures(x: dict[str, np.ndarray], minutes: float) -> dict[str, float]:
    """The figures of (steps, envs) arrays (module docstring): ``fell_fraction`` and the
    RMS tracking errors (the joystick's ``lin``, ``yaw``) or the walker's ``speed`` and
    ``targets_per_minute`` (its ``progress``, ``targets``) over an episode of ``minutes``."""
    up = x["up"]  # selected, not multiplied: a fallen env's physics may be NaN

    def mean_up(v: np.ndarray) -> float:
        return float(np.where(up, v, 0.0).sum() / max(up.sum(), 1))

    out = {"fell_fraction": float(1.0 - x["after"][-1].mean())}
    if "lin" in x:
        out["tracking_error_lin"] = math.sqrt(mean_up(x["lin"] ** 2))
        out["tracking_error_yaw"] = math.sqrt(mean_up(x["yaw"] ** 2))
    else:
        arrived = np.diff(x["targets"], axis=0, prepend=0) > 0  # targets_reached rose
        out["speed"] = mean_up(x["progress"])
        out["targets_per_minute"] = float((arrived & x["after"]).sum(0).mean() / minutes)
    return out


def evaluate(
    run_dir: str,
    physics: str | None,
    envs: int,
    seed: int,
    seconds: float,
    max_contacts: int | None = None,
    hfield_contact: str | None = None,
) -> dict[str, Any]:
    """The figures of one run (module docstring)."""
    env_id, env, act = eval_env(run_dir, physics, max_contacts, hfield_contact)
    env, steps = with_episode(env, seconds)
    start = time.perf_counter()
    out = rollout(env, act, STEP_INFO[env_id], envs, steps, seed)
    c = env.config
    minutes = steps * env.control_dt / 60.0
    result: dict[str, Any] = {
        "env_id": env_id,
        "physics": env.physics,
        "device": jax.devices()[0].device_kind,
        "envs_per_group": envs,
        "seconds": steps * env.control_dt,
        "levels": c.levels,
        "mid_level": c.levels // 2,
        "top_level": c.levels - 1,
        "types": list(c.terrain_types),
        "max_contacts": c.max_contacts,
        "hfield_contact": c.hfield_contact,
        "wall_seconds": round(time.perf_counter() - start, 2),  # compile included
    }
    types = np.arange(envs) % len(c.terrain_types)
    for params, level, x in groups(out, envs):
        per_type = {
            name: figures({k: v[:, types == t] for k, v in x.items()}, minutes)
            for t, name in enumerate(c.terrain_types)
        }
        result.setdefault(params, {})[level] = figures(x, minutes) | {"types": per_type}
    return result


def eval_file(physics: str, hfield_contact: str = "surface") -> str:
    """``rough_eval_<physics>.json``, ``rough_eval_c_mujoco.json`` for MuJoCo C with
    MuJoCo's own heightfield collider."""
    tail = "_mujoco" if physics == "c" and hfield_contact == "mujoco" else ""
    return f"rough_eval_{physics}{tail}.json"


def chunk_level(run: Path, first: bool = False) -> float:
    """The mean over seeds of progress.csv's ``level`` in the run's last (or first) chunk."""
    rows = runner.read_progress(run / runner.PROGRESS_FILE)
    if not rows or "level" not in rows[0]:
        raise SystemExit(f"{run}: progress.csv holds no level (not a curriculum run?)")
    pick = (min if first else max)(int(r["chunk"]) for r in rows)
    return float(np.mean([float(r["level"]) for r in rows if int(r["chunk"]) == pick]))


def row(run_dir: str) -> dict[str, Any]:
    """One table row (module docstring)."""
    run = Path(run_dir)
    config = runner.load_run_config(run)
    if config.env_id not in FIGURES:
        raise SystemExit(f"table: {run_dir} is a run of {config.env_id}, not a terrain task")
    summary = json.loads((run / runner.SUMMARY_FILE).read_text())
    files = {"mjx": eval_file("mjx"), "c": eval_file("c"), "c_mujoco": eval_file("c", "mujoco")}
    evals = {
        name: json.loads((run / file).read_text())
        for name, file in files.items()
        if (run / file).exists()
    }
    out: dict[str, Any] = {
        "env_id": config.env_id,
        "seed": config.train.seed,
        "run": run.name,
        "train_seconds": summary["wall_seconds"],
        "final_mean_level": round(chunk_level(run), 4),
        "first_chunk_mean_level": round(chunk_level(run, first=True), 4),
        "levels": config.env.levels,
        "env_steps": summary["env_steps"],
        "chunks": summary["chunks"],
        "num_chunks": summary["num_chunks"],
        "finished": summary["finished"],
    }
    if "mjx" in evals and evals["mjx"]["device"] != "cpu":
        out["gpu"] = evals["mjx"]["device"]
    for field, physics, params in BENCHES:
        if physics in evals:
            groups = evals[physics][params]
            out[field] = {
                level: {k: round(groups[level][k], 4) for k in FIGURES[config.env_id]}
                for level in ("mid", "top")
            }
            out[field]["mid_fell_by_type"] = {
                t: round(f["fell_fraction"], 4) for t, f in groups["mid"]["types"].items()
            }
            for level in ("mid", "top"):
                out[field][f"{level}_by_type"] = {
                    t: {k: round(f[k], 4) for k in FIGURES[config.env_id]}
                    for t, f in groups[level]["types"].items()
                }
    return out


def _parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(description=(__doc__ or "").splitlines()[0])
    sub = parser.add_subparsers(dest="command", required=True)
    ev = sub.add_parser("eval", help="measure one run")
    ev.add_argument("run_dir")
    ev.add_argument("--physics", choices=("mjx", "c"), default=None)
    ev.add_argument("--envs", type=int, default=280, help="envs per group (default 280)")
    ev.add_argument("--seed", type=int, default=123)
    ev.add_argument("--seconds", type=float, default=20.0, help="episode length (s)")
    ev.add_argument(
        "--max-contacts",
        type=int,
        default=None,
        help="MJX's contact budget for the eval (0: every contact; default: the run's)",
    )
    ev.add_argument(
        "--hfield-contact",
        choices=HFIELD_CONTACTS,
        default=None,
        help="MuJoCo C's heightfield collider for the eval (default: the run's config's)",
    )
    ev.add_argument(
        "--out", default=None, help="the eval file (default: RUN/rough_eval_<physics>.json)"
    )
    tb = sub.add_parser("table", help="one row per evaluated run")
    tb.add_argument("run_dirs", nargs="+")
    tb.add_argument("--json", metavar="NAME", required=True, help=results_io.HELP)
    tb.add_argument("--machine", default=None, help="where the runs trained and were evaluated")
    tb.add_argument(
        "--gpu", default=None, help="the GPU the runs trained on (default: the mjx eval's)"
    )
    return parser


def main(argv: list[str] | None = None) -> None:
    args = _parser().parse_args(argv)
    if args.command == "eval":
        if args.envs < 1 or not 0 < args.seconds <= 600:
            raise SystemExit("--envs must be >= 1 and --seconds in (0, 600]")
        result = evaluate(
            args.run_dir,
            args.physics,
            args.envs,
            args.seed,
            args.seconds,
            args.max_contacts,
            args.hfield_contact,
        )
        name = eval_file(result["physics"], result["hfield_contact"])
        path = Path(args.out or Path(args.run_dir) / name)
        path.write_text(json.dumps(result, indent=2) + "\n")
        brief = {k: v for k, v in result.items() if k not in ("default", "randomized")}
        for params in ("default", "randomized"):
            for level in ("mid", "top"):
                brief[f"{params}_{level}"] = {
                    k: round(result[params][level][k], 4) for k in FIGURES[result["env_id"]]
                }
        print(json.dumps(brief, indent=1))
        print(f"wrote {path}")
        return
    rows = sorted((row(r) for r in args.run_dirs), key=lambda r: r["seed"])
    ids = sorted({r["env_id"] for r in rows})
    if len(ids) > 1:
        raise SystemExit(f"table: the runs are of several tasks ({', '.join(ids)})")
    rec = results_io.record(
        args.json,
        f"{ids[0]} PPO per seed: train wall, final level, falls and "
        f"{'tracking' if 'Joystick' in ids[0] else 'walking'} at mid and top",
        rows,
        description=args.machine or "training and the mjx eval on the gpu named; C on the CPU",
        engine="mjx: mjx*; MuJoCo C: mujoco_c*",
    )
    rec["machine"]["gpu"] = (
        [args.gpu] if args.gpu else sorted({r["gpu"] for r in rows if "gpu" in r})
    )
    results_io.write(args.json, rec)
    print(json.dumps(rows, indent=2))


if __name__ == "__main__":
    main()
