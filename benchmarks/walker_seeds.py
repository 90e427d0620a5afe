"""HexapodWalk-v0 policies per seed: speed, falls and targets reached, on three benches.

``eval`` drives a trained run's greedy policy (``jaxenvs train HexapodWalk-v0 ...``) in one
batch of ``4 x --envs`` envs, each for one episode (``--episode-steps``, 1000 = 50 s):

* ``far``: the target ``--far`` metres away (no env reaches it). Over the first ``--steps``
  control steps (200 = 10 s): the mean speed toward the target (the task's ``progress``
  metric, m/s, averaged over the env-steps while the env is up; ``speed_m_per_s``) and
  the fraction of envs that fell (``fell_fraction``).
* ``near``: the target ``--near`` metres away (3 m) in a random direction: the fraction of
  envs whose body centre came within ``--radius`` (0.25 m, about a body length) of it
  before falling, within the episode (``targets_reached``). Where the run's task draws
  waypoints (``waypoint_radius`` > 0, the default), each arrival draws a new target
  ``--near`` metres away: ``targets_per_minute`` counts the arrivals while up per minute
  of the episode, averaged over the envs, and ``fell_fraction_episode`` the falls over
  the whole episode of walking from target to target.

each under the task's default physics params (``default``) and under params drawn by
``env.sample_params``, one draw per env (``randomized``: mass and inertia x0.8-1.2, foot
friction x0.7-1.3, servo kp x0.8-1.2, joint damping x0.7-1.3). ``--physics c`` runs it on
MuJoCo's C engine (CPU; set ``JAX_PLATFORMS=cpu``).

A fall is the task's DEFAULT termination (``WalkConfig()``: body below 0.06 m or tilted
more than ~45 degrees), whatever termination the run trained with, so that every run is
measured against the same line. The run's other env settings (reward terms and such, none
of which change what the policy sees or does) are kept.

``eval`` writes its figures to ``RUN/walker_eval_mjx.json`` (or ``_c.json``); ``table``
collects them, with each run's summary.json and config.yaml, into one record per run
(``benchmarks/results/ppo_walker_waypoints_h100.json``); ``slim`` writes a run's greedy policy to
``RUN/policy.npz`` (about 1 MB), which ``eval`` reads where the full ``checkpoint.npz``
(some 80 MB: it also holds the training envs' states) was not kept; ``render`` draws a
trajectory saved by ``eval --trajectory`` as an animated GIF and a strip of frames, where
MuJoCo can render (``MUJOCO_GL=egl``).

    python benchmarks/walker_seeds.py eval RUN --trajectory RUN/walk.npz
    JAX_PLATFORMS=cpu python benchmarks/walker_seeds.py eval RUN --physics c
    python benchmarks/walker_seeds.py table RUN0 RUN1 RUN2 --json ppo_walker_waypoints_h100
    MUJOCO_GL=egl python benchmarks/walker_seeds.py render RUN/walk.npz \\
        --gif benchmarks/images/hexapod_walk.gif --strip benchmarks/images/hexapod_walk_frames.png
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import time
from pathlib import Path
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
import results_io

from jaxenvs.robots.hexapod import quat_to_mat
from jaxenvs.run import runner
from jaxenvs.tasks.hexapod import HexapodWalk, WalkConfig

GROUPS = ("default_far", "default_near", "randomized_far", "randomized_near")
EVAL_FILE = "walker_eval_{}.json"  # .format(physics)


def load_policy(run_dir: str, physics: str | None) -> tuple[str, Any, Any]:
    """``runner.load_policy``: a full run directory or one that keeps only ``policy.npz``."""
    return runner.load_policy(run_dir, physics)


def slim(run_dir: str) -> Path:
    """Write the greedy policy of a run's best seed to ``policy.npz`` (``runner.save_policy``;
    a few hundred kB, where the checkpoint also holds the 8192 envs' physics states)."""
    return runner.save_policy(run_dir)


def eval_env(run_dir: str, physics: str | None) -> tuple[HexapodWalk, Any]:
    """The run's env with the task's default termination, and the run's greedy policy."""
    env_id, env, act = load_policy(run_dir, physics)
    if env_id != "HexapodWalk-v0" or not isinstance(env, HexapodWalk):
        raise SystemExit(f"{run_dir} trained {env_id}, not HexapodWalk-v0")
    task = WalkConfig()
    config = dataclasses.replace(
        env.config, min_height=task.min_height, min_upright=task.min_upright
    )
    return HexapodWalk(config), act


def evaluate(
    run_dir: str,
    physics: str | None = None,
    envs: int = 256,
    steps: int = 200,
    episode_steps: int = 1000,
    far: float = 50.0,
    near: float = 3.0,
    radius: float = 0.25,
    seed: int = 123,
) -> tuple[dict[str, Any], dict[str, np.ndarray]]:
    """The figures of one run (see the module docstring) and env 0's poses of each group."""
    env, act = eval_env(run_dir, physics)
    if near <= env.config.waypoint_radius:
        raise SystemExit(f"--near {near} m must exceed the task's waypoint_radius")
    n = envs
    params_key, reset_key = jax.random.split(jax.random.key(seed))
    base = env.default_params
    drawn = jax.vmap(env.sample_params)(jax.random.split(params_key, 2 * n))

    default = jax.tree.map(lambda x: jnp.broadcast_to(x, (2 * n, *x.shape)), base)
    params = jax.tree.map(lambda *xs: jnp.concatenate(xs), default, drawn)  # GROUPS' order
    targets = jnp.repeat(jnp.asarray([far, near, far, near], jnp.float32), n)
    params = params.replace(target_range=jnp.stack([targets, targets], 1))

    @jax.jit
    def rollout(params: Any, key: jax.Array) -> Any:
        state = jax.vmap(env.reset)(jax.random.split(key, 4 * n), params)

        def body(carry, _):  # type: ignore[no-untyped-def]
            s, up = carry
            a = jax.vmap(act)(s.obs, jax.random.split(s.key[0], 4 * n))
            s = jax.vmap(env.step)(s, a, params)
            up_after = up & ~s.terminated
            low = s.data.qpos[:, 2] < env.config.min_height
            upright = jax.vmap(quat_to_mat)(s.data.qpos[:, 3:7])[:, 2, 2]
            reached = s.info["targets_reached"]
            out = (s.info["progress"], s.info["distance"], upright, low, up, up_after, reached)
            pose = (s.data.qpos[0::n], s.data.mocap_pos[0::n, 0])
            return (s, up_after), (out, pose)

        carry = (state, jnp.ones(4 * n, bool))
        _, (out, pose) = jax.lax.scan(body, carry, None, length=episode_steps)
        return out, pose

    start = time.perf_counter()
    out, pose = jax.device_get(rollout(params, reset_key))
    seconds = time.perf_counter() - start
    # (episode_steps, 4n) each; ``up``: up before the step, ``after``: still up after it
    progress, distance, upright, low, up, after, count = (np.asarray(x) for x in out)
    arrivals = np.diff(count, axis=0, prepend=0.0) * up  # an arrival on a step begun up
    result: dict[str, Any] = {
        "physics": env.physics,
        "device": jax.devices()[0].device_kind,
        "envs_per_group": n,
        "steps": steps,
        "seconds": steps * env.control_dt,
        "episode_steps": episode_steps,
        "far_m": far,
        "near_m": near,
        "radius_m": radius,
        "waypoint_radius_m": env.config.waypoint_radius,
        "wall_seconds": round(seconds, 2),  # compile included
    }
    for g, name in enumerate(GROUPS):
        cols = slice(g * n, (g + 1) * n)
        fields = (progress, distance, upright, low, up, after, arrivals)
        p, d, z, lo, u, a, arr = (x[:, cols] for x in fields)
        stats: dict[str, Any] = {}
        if name.endswith("far"):
            # an env that fell keeps stepping, and under C its physics can blow up (NaN)
            # after the fall: only the steps while up count, so mask by selection, not by
            # multiplying by 0 (NaN * 0 is NaN)
            w = u[:steps]
            pw = np.where(w, p[:steps], 0.0)
            stats["speed_m_per_s"] = float(pw.sum() / max(w.sum(), 1))
            per_env = pw.sum(0) / np.maximum(w.sum(0), 1)
            stats["speed_per_env_min"] = float(per_env.min())
            stats["fell_fraction"] = float(1.0 - a[steps - 1].mean())
            stats["mean_upright"] = float(np.where(w, z[:steps], 0.0).sum() / max(w.sum(), 1))
        else:
            close = (d < radius) & u
            reached = close.any(0)
            stats["targets_reached"] = float(reached.mean())
            first = close.argmax(0)[reached] + 1
            stats["reach_seconds_median"] = (
                float(np.median(first) * env.control_dt) if reached.any() else None
            )
            stats["min_distance_median_m"] = float(np.median(np.where(u, d, np.inf).min(0)))
            minutes = episode_steps * env.control_dt / 60.0
            stats["targets_per_minute"] = float(arr.sum(0).mean() / minutes)
        # falls over the whole episode, and what ended them (height or tilt)
        fell = ~a[-1]
        fall_step = (~a).argmax(0)[fell]
        by_height = int(lo[fall_step, np.flatnonzero(fell)].sum())
        stats["fell_fraction_episode"] = float(fell.mean())
        stats["falls_by_height"] = by_height
        stats["falls_by_tilt"] = int(fell.sum()) - by_height
        stats["fall_seconds"] = sorted(round(float(t + 1) * env.control_dt, 2) for t in fall_step)
        result[name] = stats
    poses = {
        f"{name}_{field}": np.asarray(x[:, g])
        for g, name in enumerate(GROUPS)
        for field, x in zip(("qpos", "mocap_pos"), pose, strict=True)
    }
    return result, poses


def brief(result: dict[str, Any]) -> dict[str, Any]:
    """The figures of ``evaluate`` without the per-fall times, rounded, for a terminal."""
    out: dict[str, Any] = {}
    for k, v in result.items():
        if isinstance(v, dict):
            v = {f: round(x, 4) if isinstance(x, float) else x for f, x in v.items()}
            v["falls_within_2s"] = sum(t <= 2.0 for t in v.pop("fall_seconds"))
        out[k] = v
    return out


def config_diff(run: Path) -> dict[str, Any]:
    """The run's env and agent settings that differ from the shipped config's (``{}``: the
    shipped config; the engine and the seed aside)."""
    ran = runner.load_run_config(run).to_dict()
    shipped = runner.resolve_config("HexapodWalk-v0", "ppo").to_dict()
    return {
        f"{section}.{k}": v
        for section in ("env", "agent")
        for k, v in ran[section].items()
        if k != "physics" and shipped[section].get(k) != v
    }


def table(run_dirs: list[str]) -> list[dict[str, Any]]:
    """One record per run (seed) from its summary.json, config.yaml and eval files."""
    keys = ("speed_m_per_s", "fell_fraction", "targets_reached")
    near_keys = ("targets_per_minute",)
    rows = []
    for run_dir in run_dirs:
        run = Path(run_dir)
        summary = json.loads((run / runner.SUMMARY_FILE).read_text())
        resolved = runner.load_run_config(run)
        mjx_eval = json.loads((run / EVAL_FILE.format("mjx")).read_text())
        row: dict[str, Any] = {
            "seed": resolved.train.seed,
            "run": run.name,
            "train_seconds": summary["wall_seconds"],
            # the first chunk's wall: mostly compile (short where the compile cache was warm)
            "first_chunk_seconds": float(
                runner.read_progress(run / runner.PROGRESS_FILE)[0]["wall_seconds"]
            ),
            "gpu": mjx_eval["device"],
            "env_steps": summary["env_steps"],
            "eval_mean_return": summary["eval_mean_return"],
            "config_diff": config_diff(run),
        }

        def figures(ev: dict[str, Any], kind: str) -> dict[str, Any]:
            far, near = ev[f"{kind}_far"], ev[f"{kind}_near"]
            out = {k: round((far | near)[k], 4) for k in keys}
            out["fell_fraction_episode"] = round(far["fell_fraction_episode"], 4)
            out["fell_fraction_episode_near"] = round(near["fell_fraction_episode"], 4)
            out |= {k: round(near[k], 4) for k in near_keys if k in near}
            return out

        row |= figures(mjx_eval, "default")
        row["randomized"] = figures(mjx_eval, "randomized")
        c_file = run / EVAL_FILE.format("c")
        if c_file.exists():
            c_eval = json.loads(c_file.read_text())
            row["mujoco_c"] = figures(c_eval, "default")
            row["mujoco_c_randomized"] = figures(c_eval, "randomized")
        rows.append(row)
    return sorted(rows, key=lambda r: r["seed"])


def render(
    trajectory: str, group: str, gif: str | None, strip: str | None, seconds: float | None = None
) -> None:
    """Draw env 0 of ``group`` from a saved trajectory: a GIF (every other control step,
    over the first ``seconds``, or until 1 s after the first target is reached) and/or a
    strip of 5 frames."""
    import imageio.v2 as imageio

    from jaxenvs import make
    from jaxenvs import render as rendering

    env = make("HexapodWalk-v0")
    pose = np.load(trajectory)
    qpos, target = pose[f"{group}_qpos"], pose[f"{group}_mocap_pos"]
    # the first arrival: where the saved target moves (a waypoint drawn: the pose is saved
    # after the step), or where the body comes within 0.25 m of a target that stays
    moved = np.flatnonzero(np.any(np.diff(target[:, :2], axis=0) != 0, axis=1))
    close = np.flatnonzero(np.linalg.norm(qpos[:, :2] - target[:, :2], axis=1) < 0.25)
    arrivals = [int(i) + 1 for i in moved[:1]] + [int(i) for i in close[:1]]
    end = len(qpos)
    if seconds is not None:
        end = min(end, round(seconds / env.control_dt))
    elif group.endswith("near") and arrivals:
        end = min(end, min(arrivals) + round(1 / env.control_dt))
    with rendering.Renderer(env, 320, 240, None) as renderer:
        # the model's one light is fixed above the start; a headlight keeps the walker lit
        renderer.model.vis.headlight.ambient[:] = 0.35
        renderer.model.vis.headlight.diffuse[:] = 0.55
        frames = [renderer.frame(q, m[None]) for q, m in zip(qpos[:end], target[:end], strict=True)]
    if gif:
        imageio.mimsave(gif, frames[::2], duration=2 * env.control_dt * 1000, loop=0)
        print(f"gif: {gif} ({len(frames[::2])} frames, {Path(gif).stat().st_size} bytes)")
    if strip:
        picks = np.linspace(0, end - 1, 5).round().astype(int)
        imageio.imwrite(strip, np.concatenate([frames[i] for i in picks], axis=1))
        times = ", ".join(f"{i * env.control_dt:.1f}" for i in picks)
        print(f"strip: {strip} (t = {times} s)")


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=(__doc__ or "").splitlines()[0])
    sub = parser.add_subparsers(dest="command", required=True)
    ev = sub.add_parser("eval", help="measure one run")
    ev.add_argument("run_dir")
    ev.add_argument("--physics", choices=("mjx", "c"), default=None)
    ev.add_argument("--envs", type=int, default=256, help="envs per group")
    ev.add_argument("--steps", type=int, default=200, help="control steps for speed and falls")
    ev.add_argument("--episode-steps", type=int, default=1000, help="steps to reach the target")
    ev.add_argument("--far", type=float, default=50.0, help="far target distance (m)")
    ev.add_argument("--near", type=float, default=3.0, help="near target distance (m)")
    ev.add_argument("--radius", type=float, default=0.25, help="reached within this (m)")
    ev.add_argument("--seed", type=int, default=123)
    ev.add_argument("--trajectory", metavar="OUT.npz", help="save env 0's poses per group")
    sl = sub.add_parser("slim", help="write a run's greedy policy to RUN/policy.npz")
    sl.add_argument("run_dir")
    tb = sub.add_parser("table", help="per-seed records of evaluated runs")
    tb.add_argument("run_dirs", nargs="+")
    tb.add_argument("--json", metavar="NAME", required=True, help=results_io.HELP)
    rd = sub.add_parser("render", help="draw a saved trajectory")
    rd.add_argument("trajectory")
    rd.add_argument("--group", choices=GROUPS, default="default_near")
    rd.add_argument("--gif", metavar="OUT.gif")
    rd.add_argument("--strip", metavar="OUT.png")
    rd.add_argument("--seconds", type=float, help="draw the first SECONDS of the episode")
    args = parser.parse_args(argv)

    if args.command == "eval":
        result, poses = evaluate(
            args.run_dir,
            args.physics,
            args.envs,
            args.steps,
            args.episode_steps,
            args.far,
            args.near,
            args.radius,
            args.seed,
        )
        print(json.dumps(brief(result), indent=1))
        out = Path(args.run_dir) / EVAL_FILE.format(result["physics"])
        out.write_text(json.dumps(result, indent=2) + "\n")
        if args.trajectory:
            np.savez_compressed(args.trajectory, **poses)
    elif args.command == "slim":
        print(f"policy: {slim(args.run_dir)}")
    elif args.command == "table":
        rows = table(args.run_dirs)
        title = "HexapodWalk-v0 PPO per seed: train wall, greedy speed, falls, targets reached"
        rec = results_io.record(args.json, title, rows, engine="mjx; mujoco_c* fields under C")
        gpus = sorted({r["gpu"] for r in rows})
        rec["machine"] |= {"description": "where each run trained (its gpu field)", "gpu": gpus}
        results_io.write(args.json, rec)
        print(json.dumps(rows, indent=2))
    else:
        render(args.trajectory, args.group, args.gif, args.strip, args.seconds)


if __name__ == "__main__":
    main()
