"""Trained hexapod policies per seed: one evaluator, a small section per task.

The task is read from the run directory (``config.yaml``); :data:`TASKS` maps each env id
to its :class:`Task`: what the evaluation measures, with which options, and how a
``table`` record holds it. Adding a task (say a terrain variant of the joystick) is one
entry there.

    python benchmarks/seeds.py slim RUN                       # RUN/policy.npz (~1 MB)
    python benchmarks/seeds.py eval RUN [--physics c] [--envs N] [--trajectory OUT.npz]
    python benchmarks/seeds.py table RUN0 RUN1 RUN2 --json NAME    # benchmarks/results/NAME.json
    MUJOCO_GL=egl python benchmarks/seeds.py render RUN/walk.npz \\
        --gif benchmarks/images/hexapod_walk.gif --strip benchmarks/images/hexapod_walk_frames.png
    MUJOCO_GL=egl JAX_PLATFORMS=cpu python benchmarks/seeds.py drive RUN --physics c \\
        --gif benchmarks/images/hexapod_joystick.gif

``eval`` drives the run's greedy policy in one batch of envs, each for one episode, half of
them under the task's default physics params (groups ``default*``) and half under params
drawn by ``env.sample_params``, one draw per env (``randomized*``: mass and inertia
x0.8-1.2, foot friction x0.7-1.3, servo kp x0.8-1.2, joint damping x0.7-1.3), and writes
``RUN/<task>_eval_<physics>.json``. ``--physics c`` runs it on MuJoCo's C engine (CPU; set
``JAX_PLATFORMS=cpu``). A fall is the task's DEFAULT termination (body below 0.06 m or
tilted more than ~45 degrees), whatever termination the run trained with, so every run is
measured against the same line; the run's other env settings are kept. ``slim`` writes
the best seed's greedy policy to ``RUN/policy.npz``, which ``eval`` reads where the full
``checkpoint.npz`` (some 80 MB: it also holds the training envs' states) was not kept.
``table`` collects the eval files, with each run's summary.json and config.yaml, into
one record per run.

**HexapodWalk-v0** (``walker``): groups ``far`` and ``near`` under each physics.
``far``: the target ``--far`` metres away (no env reaches it); over the first ``--steps``
control steps (200 = 10 s), the mean speed toward it (the task's ``progress`` metric,
while up; ``speed_m_per_s``) and the fraction that fell (``fell_fraction``). ``near``: the
target ``--near`` metres away in a random direction: the fraction of envs whose body came
within ``--radius`` of it before falling (``targets_reached``); with waypoints (the task's
``waypoint_radius`` > 0), each arrival draws a new target ``--near`` metres away and
``targets_per_minute`` counts the arrivals while up. ``fell_fraction_episode``: falls over
the whole episode (``--episode-steps``, 1000 = 50 s). ``render`` draws a trajectory saved
by ``eval --trajectory`` as an animated GIF and a strip of frames.

**HexapodJoystick-v0** (``joystick``): episodes of ``--seconds`` (20 s) with the command
redrawn on the task's schedule over the run's full command ranges, pushes and action noise
off; the run's observation noise, action delay and sensor biases kept. Per group:
``tracking_error_lin`` (RMS over the env-steps while up of |command - velocity| in the
horizontal plane, m/s, the body's mean velocity over the control step in its heading
frame), ``tracking_error_yaw`` (the same of the yaw rate, rad/s), ``*_settled`` (without
the first second after each command change) and ``fell_fraction``. ``drive`` plays
:data:`SEQUENCE` (forward, turning, sideways, backwards, on the spot, standing) through the
task's ``with_command`` and prints the mean velocity under each command.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import time
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
import results_io

from jaxenvs.robots.hexapod import quat_to_mat
from jaxenvs.run import runner

Arrays = dict[str, np.ndarray]


@dataclasses.dataclass(frozen=True)
class Task:
    """What ``eval`` and ``table`` do for one env id (module docstring).

    ``settings``: a frozen dataclass of the task's eval options (each field a ``--flag``).
    ``variants``: the groups under each physics (``("far", "near")``; ``("",)`` for one).
    ``eval_config``: env config fields set for the evaluation besides the default
    termination. ``prepare(env, params, settings, n)``: the params of all groups, edited
    per group (``n`` envs each). ``length(env, settings)``: control steps of an episode.
    ``record(env, before, after)``: per step, a dict of per-env arrays and a dict of
    arrays whose env 0 of each group goes to the trajectory. ``figures(variant, arrays,
    settings, env)``: one group's figures from its (steps, envs) arrays (``up``,
    ``after`` and ``low`` included). ``header(env, settings, steps)``: the eval file's
    settings. ``row(run, resolved, evals)``: a table record's task fields from the eval
    files (by engine). ``render(trajectory, args)`` and ``drive(run_dir, args)``: the
    task's drawings, if any.
    """

    name: str
    title: str
    settings: type
    variants: tuple[str, ...]
    prepare: Callable[[Any, Any, Any, int], Any]
    length: Callable[[Any, Any], int]
    record: Callable[[Any, Any, Any], tuple[dict[str, jax.Array], dict[str, jax.Array]]]
    figures: Callable[[str, Arrays, Any, Any], dict[str, Any]]
    header: Callable[[Any, Any, int], dict[str, Any]]
    row: Callable[[Path, Any, dict[str, dict[str, Any]]], dict[str, Any]]
    engine: str
    machine: str
    eval_config: Mapping[str, Any] = dataclasses.field(default_factory=dict)
    render: Callable[[str, argparse.Namespace], None] | None = None
    drive: Callable[[str, argparse.Namespace], None] | None = None

    def groups(self) -> tuple[str, ...]:
        """The groups in batch order: every variant under default, then randomised params."""
        return tuple(
            f"{physics}_{v}" if v else physics
            for physics in ("default", "randomized")
            for v in self.variants
        )

    def eval_file(self, physics: str) -> str:
        return f"{self.name}_eval_{physics}.json"


# ------------------------------------------------------------------------- shared parts
def task_of(env_id: str) -> Task:
    """The :class:`Task` of ``env_id``; a one-line error for a task without one."""
    if env_id not in TASKS:
        raise SystemExit(f"no seeds evaluation for {env_id}; tasks: {', '.join(TASKS)}")
    return TASKS[env_id]


def eval_env(run_dir: str, physics: str | None) -> tuple[Task, Any, Any]:
    """The run's task entry, its env with the task's default termination (and the task's
    ``eval_config``), and the run's greedy policy."""
    env_id, env, act = runner.load_policy(run_dir, physics)
    task = task_of(env_id)
    default = type(env.config)()
    config = dataclasses.replace(
        env.config,
        min_height=default.min_height,
        min_upright=default.min_upright,
        **task.eval_config,
    )
    return task, type(env)(config), act


def falls(after: np.ndarray, low: np.ndarray, dt: float) -> dict[str, Any]:
    """Falls over the whole episode (``after``: still up after each step, (steps, envs))
    and what ended them (``low``: the body below the height line, else the tilt)."""
    fell = ~after[-1]
    fall_step = (~after).argmax(0)[fell]
    by_height = int(low[fall_step, np.flatnonzero(fell)].sum())
    return {
        "fell_fraction_episode": float(fell.mean()),
        "falls_by_height": by_height,
        "falls_by_tilt": int(fell.sum()) - by_height,
        "fall_seconds": sorted(round(float(t + 1) * dt, 2) for t in fall_step),
    }


def masked_mean(x: np.ndarray, mask: np.ndarray) -> float:
    """The mean of ``x`` where ``mask``: selected, not multiplied (a fallen env keeps
    stepping, and under C its physics can blow up to NaN, and NaN x 0 is NaN)."""
    return float(np.where(mask, x, 0.0).sum() / max(mask.sum(), 1))


def evaluate(
    run_dir: str, physics: str | None = None, envs: int = 256, seed: int = 123, **options: Any
) -> tuple[dict[str, Any], Arrays]:
    """The figures of one run (module docstring) and env 0's trajectory of each group."""
    task, env, act = eval_env(run_dir, physics)
    settings = task.settings(**options)
    n, total = envs, 2 * len(task.variants) * envs
    params_key, reset_key = jax.random.split(jax.random.key(seed))
    drawn = jax.vmap(env.sample_params)(jax.random.split(params_key, total // 2))
    default = jax.tree.map(
        lambda x: jnp.broadcast_to(x, (total // 2, *x.shape)), env.default_params
    )
    params = jax.tree.map(lambda *xs: jnp.concatenate(xs), default, drawn)  # groups' order
    params = task.prepare(env, params, settings, n)
    steps = task.length(env, settings)

    @jax.jit
    def rollout(params: Any, key: jax.Array) -> Any:
        state = jax.vmap(env.reset)(jax.random.split(key, total), params)

        def body(carry, _):  # type: ignore[no-untyped-def]
            s, up = carry
            a = jax.vmap(act)(s.obs, jax.random.split(s.key[0], total))
            nxt = jax.vmap(env.step)(s, a, params)
            after = up & ~nxt.terminated
            low = nxt.data.qpos[:, 2] < env.config.min_height
            out, show = task.record(env, s, nxt)
            out |= {"up": up, "after": after, "low": low}
            return (nxt, after), (out, {k: x[0::n] for k, x in show.items()})

        _, (out, show) = jax.lax.scan(body, (state, jnp.ones(total, bool)), None, length=steps)
        return out, show

    start = time.perf_counter()
    out, show = jax.device_get(rollout(params, reset_key))
    wall = time.perf_counter() - start
    result: dict[str, Any] = {
        "physics": env.physics,
        "device": jax.devices()[0].device_kind,
        "envs_per_group": n,
        **task.header(env, settings, steps),
        "wall_seconds": round(wall, 2),  # compile included
    }
    groups = task.groups()
    for g, name in enumerate(groups):
        arrays = {k: np.asarray(x)[:, g * n : (g + 1) * n] for k, x in out.items()}
        result[name] = task.figures(name.rpartition("_")[2], arrays, settings, env)
    trajectory = {
        f"{name}_{field}": np.asarray(x)[:, g]
        for g, name in enumerate(groups)
        for field, x in show.items()
    }
    return result, trajectory


def brief(task: Task, result: dict[str, Any]) -> dict[str, Any]:
    """The figures of :func:`evaluate` rounded, without the per-fall times (the falls
    within 2 s counted instead), for a terminal."""
    out: dict[str, Any] = {}
    for k, v in result.items():
        if k in task.groups():
            v = {f: round(x, 4) if isinstance(x, float) else x for f, x in v.items()}
            v["falls_within_2s"] = sum(t <= 2.0 for t in v.pop("fall_seconds"))
        out[k] = v
    return out


def table(run_dirs: list[str]) -> tuple[Task, list[dict[str, Any]]]:
    """One record per run (seed) from its summary.json, config.yaml and eval files; every
    run must be of one task."""
    resolved = [runner.load_run_config(Path(r)) for r in run_dirs]
    ids = sorted({r.env_id for r in resolved})
    if len(ids) != 1:
        raise SystemExit(f"table: the runs trained different tasks ({', '.join(ids)})")
    task = task_of(ids[0])
    rows = []
    for run_dir, config in zip(run_dirs, resolved, strict=True):
        run = Path(run_dir)
        summary = json.loads((run / runner.SUMMARY_FILE).read_text())
        evals = {
            physics: json.loads((run / task.eval_file(physics)).read_text())
            for physics in ("mjx", "c")
            if (run / task.eval_file(physics)).exists()
        }
        row: dict[str, Any] = {
            "seed": config.train.seed,
            "run": run.name,
            "train_seconds": summary["wall_seconds"],
            # the first chunk's wall: mostly compile (short where the compile cache was warm)
            "first_chunk_seconds": float(
                runner.read_progress(run / runner.PROGRESS_FILE)[0]["wall_seconds"]
            ),
        }
        if "mjx" in evals:
            row["gpu"] = evals["mjx"]["device"]
        row |= {"env_steps": summary["env_steps"], "eval_mean_return": summary["eval_mean_return"]}
        rows.append(row | task.row(run, config, evals))
    return task, sorted(rows, key=lambda r: r["seed"])


def _option(default: Any, help: str) -> Any:
    """A field of a task's eval settings: its default and its ``--flag``'s help."""
    return dataclasses.field(default=default, metadata={"help": help})


# ----------------------------------------------------------------------- HexapodWalk-v0
@dataclasses.dataclass(frozen=True)
class WalkSettings:
    """The walker's eval options (module docstring)."""

    steps: int = _option(200, "control steps for speed and falls")
    episode_steps: int = _option(1000, "steps to reach the target")
    far: float = _option(50.0, "far target distance (m)")
    near: float = _option(3.0, "near target distance (m)")
    radius: float = _option(0.25, "reached within this (m)")


def walk_prepare(env: Any, params: Any, s: WalkSettings, n: int) -> Any:
    if s.near <= env.config.waypoint_radius:
        raise SystemExit(f"--near {s.near} m must exceed the task's waypoint_radius")
    targets = jnp.repeat(jnp.asarray([s.far, s.near, s.far, s.near], jnp.float32), n)
    return params.replace(target_range=jnp.stack([targets, targets], 1))


def walk_record(env: Any, before: Any, s: Any) -> tuple[dict[str, Any], dict[str, Any]]:
    upright = jax.vmap(quat_to_mat)(s.data.qpos[:, 3:7])[:, 2, 2]
    out = {
        "progress": s.info["progress"],
        "distance": s.info["distance"],
        "upright": upright,
        "reached": s.info["targets_reached"],
    }
    return out, {"qpos": s.data.qpos, "mocap_pos": s.data.mocap_pos[:, 0]}


def walk_figures(variant: str, x: Arrays, s: WalkSettings, env: Any) -> dict[str, Any]:
    up, dt = x["up"], env.control_dt
    stats: dict[str, Any] = {}
    if variant == "far":
        w = up[: s.steps]
        pw = np.where(w, x["progress"][: s.steps], 0.0)
        stats["speed_m_per_s"] = masked_mean(x["progress"][: s.steps], w)
        stats["speed_per_env_min"] = float((pw.sum(0) / np.maximum(w.sum(0), 1)).min())
        stats["fell_fraction"] = float(1.0 - x["after"][s.steps - 1].mean())
        stats["mean_upright"] = masked_mean(x["upright"][: s.steps], w)
    else:
        close = (x["distance"] < s.radius) & up
        reached = close.any(0)
        stats["targets_reached"] = float(reached.mean())
        first = close.argmax(0)[reached] + 1
        stats["reach_seconds_median"] = float(np.median(first) * dt) if reached.any() else None
        stats["min_distance_median_m"] = float(
            np.median(np.where(up, x["distance"], np.inf).min(0))
        )
        arrivals = np.diff(x["reached"], axis=0, prepend=0.0) * up  # on a step begun up
        stats["targets_per_minute"] = float(arrivals.sum(0).mean() / (s.episode_steps * dt / 60))
    return stats | falls(x["after"], x["low"], dt)


def walk_header(env: Any, s: WalkSettings, steps: int) -> dict[str, Any]:
    return {
        "steps": s.steps,
        "seconds": s.steps * env.control_dt,
        "episode_steps": s.episode_steps,
        "far_m": s.far,
        "near_m": s.near,
        "radius_m": s.radius,
        "waypoint_radius_m": env.config.waypoint_radius,
    }


def walk_row(run: Path, resolved: Any, evals: dict[str, dict[str, Any]]) -> dict[str, Any]:
    """The config's differences from the shipped one, and the figures: top level under
    MJX's default physics, ``randomized``, ``mujoco_c`` and ``mujoco_c_randomized``."""
    ran = resolved.to_dict()
    shipped = runner.resolve_config(resolved.env_id, "ppo").to_dict()
    row: dict[str, Any] = {
        "config_diff": {
            f"{section}.{k}": v
            for section in ("env", "agent")
            for k, v in ran[section].items()
            if k != "physics" and shipped[section].get(k) != v
        }
    }

    def figures(ev: dict[str, Any], kind: str) -> dict[str, Any]:
        far, near = ev[f"{kind}_far"], ev[f"{kind}_near"]
        keys = ("speed_m_per_s", "fell_fraction", "targets_reached")
        out = {k: round((far | near)[k], 4) for k in keys}
        out["fell_fraction_episode"] = round(far["fell_fraction_episode"], 4)
        out["fell_fraction_episode_near"] = round(near["fell_fraction_episode"], 4)
        if "targets_per_minute" in near:
            out["targets_per_minute"] = round(near["targets_per_minute"], 4)
        return out

    row |= figures(evals["mjx"], "default")
    row["randomized"] = figures(evals["mjx"], "randomized")
    if "c" in evals:
        row["mujoco_c"] = figures(evals["c"], "default")
        row["mujoco_c_randomized"] = figures(evals["c"], "randomized")
    return row


def walk_render(trajectory: str, args: argparse.Namespace) -> None:
    """Draw env 0 of ``--group`` from a saved trajectory: a GIF (every other control step,
    over the first ``--seconds``, or until 1 s after the first target is reached) and/or a
    strip of 5 frames."""
    import imageio.v2 as imageio

    from jaxenvs import make
    from jaxenvs import render as rendering

    env = make("HexapodWalk-v0")
    pose = np.load(trajectory)
    if f"{args.group}_qpos" not in pose:
        raise SystemExit(f"render: --group {args.group}: choose from {', '.join(WALKER.groups())}")
    qpos, target = pose[f"{args.group}_qpos"], pose[f"{args.group}_mocap_pos"]
    # the first arrival: where the saved target moves (a waypoint drawn: the pose is saved
    # after the step), or where the body comes within 0.25 m of a target that stays
    moved = np.flatnonzero(np.any(np.diff(target[:, :2], axis=0) != 0, axis=1))
    close = np.flatnonzero(np.linalg.norm(qpos[:, :2] - target[:, :2], axis=1) < 0.25)
    arrivals = [int(i) + 1 for i in moved[:1]] + [int(i) for i in close[:1]]
    end = len(qpos)
    if args.seconds is not None:
        end = min(end, round(args.seconds / env.control_dt))
    elif args.group.endswith("near") and arrivals:
        end = min(end, min(arrivals) + round(1 / env.control_dt))
    with rendering.Renderer(env, 320, 240, None) as renderer:
        # the model's one light is fixed above the start; a headlight keeps the walker lit
        renderer.model.vis.headlight.ambient[:] = 0.35
        renderer.model.vis.headlight.diffuse[:] = 0.55
        frames = [renderer.frame(q, m[None]) for q, m in zip(qpos[:end], target[:end], strict=True)]
    if args.gif:
        imageio.mimsave(args.gif, frames[::2], duration=2 * env.control_dt * 1000, loop=0)
        print(f"gif: {args.gif} ({len(frames[::2])} frames, {Path(args.gif).stat().st_size} bytes)")
    if args.strip:
        picks = np.linspace(0, end - 1, 5).round().astype(int)
        imageio.imwrite(args.strip, np.concatenate([frames[i] for i in picks], axis=1))
        times = ", ".join(f"{i * env.control_dt:.1f}" for i in picks)
        print(f"strip: {args.strip} (t = {times} s)")


# ------------------------------------------------------------------- HexapodJoystick-v0
@dataclasses.dataclass(frozen=True)
class JoystickSettings:
    """The joystick's eval options (module docstring)."""

    seconds: float = _option(20.0, "episode length (s)")


JOYSTICK_FIGURES = (
    "tracking_error_lin",
    "tracking_error_yaw",
    "fell_fraction",
    "tracking_error_lin_settled",
    "tracking_error_yaw_settled",
)
#: (engine, record field, group) of each bench in a ``table`` record
JOYSTICK_BENCHES = (
    ("mjx", "mjx", "default"),
    ("mjx", "mjx_randomized", "randomized"),
    ("c", "mujoco_c", "default"),
    ("c", "mujoco_c_randomized", "randomized"),
)


def joystick_record(env: Any, before: Any, s: Any) -> tuple[dict[str, Any], dict[str, Any]]:
    vel = jax.vmap(env.velocity)(before.data, s.data)
    out = {"lin": s.info["lin_error"], "yaw": s.info["yaw_error"], "since": s.extras.since}
    return out, {"qpos": s.data.qpos, "command": s.extras.command, "velocity": vel}


def joystick_figures(variant: str, x: Arrays, s: JoystickSettings, env: Any) -> dict[str, Any]:
    def rms(err: np.ndarray, mask: np.ndarray) -> float:
        return float(np.sqrt(masked_mean(err * err, mask)))

    up = x["up"]
    settled = up & (x["since"] >= round(1.0 / env.control_dt))
    stats: dict[str, Any] = {
        "tracking_error_lin": rms(x["lin"], up),
        "tracking_error_yaw": rms(x["yaw"], up),
        "fell_fraction": float(1.0 - x["after"][-1].mean()),
        "tracking_error_lin_settled": rms(x["lin"], settled),
        "tracking_error_yaw_settled": rms(x["yaw"], settled),
    }
    f = falls(x["after"], x["low"], env.control_dt)
    return stats | {k: f[k] for k in ("falls_by_height", "fall_seconds")}


def joystick_header(env: Any, s: JoystickSettings, steps: int) -> dict[str, Any]:
    c = env.config
    return {
        "steps": steps,
        "seconds": steps * env.control_dt,
        "command_interval_s": c.command_interval * env.control_dt,
        "command_ranges": {
            "vx": list(c.vx_range),
            "vy": list(c.vy_range),
            "yaw": list(c.yaw_range),
            "zero_probability": c.zero_probability,
        },
        "settle_s": round(1.0 / env.control_dt) * env.control_dt,
        "action_delay_max": c.action_delay_max,
        "sensor_bias": {"joint": c.joint_bias, "gyro": c.gyro_bias},
    }


def joystick_row(run: Path, resolved: Any, evals: dict[str, dict[str, Any]]) -> dict[str, Any]:
    """What the run trained with for the robot's link and the critic, and the figures of
    each bench that was evaluated."""
    env, agent = resolved.env, resolved.agent
    row: dict[str, Any] = {
        "action_delay_max": env.action_delay_max,
        "sensor_bias": {"joint": env.joint_bias, "gyro": env.gyro_bias},
        # the metrics the critic saw besides the observation (PPO's critic_info)
        "critic_info": list(agent.critic_info),
    }
    for physics, field, group in JOYSTICK_BENCHES:
        if physics in evals:
            row[field] = {k: round(evals[physics][group][k], 4) for k in JOYSTICK_FIGURES}
    return row


#: the command sequence ``drive`` plays: (seconds, (vx m/s, vy m/s, yaw rate rad/s))
SEQUENCE = (
    (4.0, (0.3, 0.0, 0.0)),
    (4.0, (0.2, 0.0, 0.6)),
    (3.0, (0.0, -0.2, 0.0)),
    (3.0, (-0.2, 0.0, 0.0)),
    (3.0, (0.0, 0.0, -0.8)),
    (2.0, (0.0, 0.0, 0.0)),
)


def joystick_drive(run_dir: str, args: argparse.Namespace) -> None:
    """Play :data:`SEQUENCE` with the run's greedy policy in one env (default physics, no
    pushes), print the mean velocity under each command (after its first second) and
    draw it with ``--gif``."""
    _, env, act = eval_env(run_dir, args.physics)
    commands = np.concatenate(
        [np.tile(cmd, (round(t / env.control_dt), 1)) for t, cmd in SEQUENCE]
    ).astype(np.float32)

    @jax.jit
    def play(key: jax.Array, commands: jax.Array) -> Any:
        def body(s, cmd):  # type: ignore[no-untyped-def]
            s = env.with_command(s, cmd)
            prev = s.data
            s = env.step(s, act(s.obs, s.key))
            return s, (s.data.qpos, env.velocity(prev, s.data), s.terminated)

        return jax.lax.scan(body, env.reset(key), commands)[1]

    qpos, velocity, fell = (np.asarray(x) for x in play(jax.random.key(0), commands))
    start = 0
    for seconds, cmd in SEQUENCE:
        end = start + round(seconds / env.control_dt)
        v = velocity[start + round(1.0 / env.control_dt) : end].mean(0)
        print(f"command {cmd}: mean velocity {tuple(round(float(x), 3) for x in v)}")
        start = end
    print(f"fell: {bool(fell.any())}")
    if args.gif:
        render_drive({"qpos": qpos, "command": commands}, args.gif)


def render_drive(
    path: dict[str, np.ndarray],
    gif: str,
    lead: float = 1.5,
    every: int = 3,
    env_id: str = "HexapodJoystick-v0",
) -> None:
    """An animated GIF of a drive of ``env_id``'s robot on its ground (every ``every``
    control steps); the red marker sits where the command would take the body in ``lead``
    seconds (vx, vy in its heading)."""
    import imageio.v2 as imageio

    from jaxenvs import make
    from jaxenvs import render as rendering

    env = make(env_id, physics="c")
    frames = []
    with rendering.Renderer(env, 240, 180, None) as renderer:
        renderer.model.vis.headlight.ambient[:] = 0.35
        renderer.model.vis.headlight.diffuse[:] = 0.55
        for q, cmd in zip(path["qpos"][::every], path["command"][::every], strict=True):
            w, x, y, z = q[3:7]
            yaw = np.arctan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z))  # heading
            c, s = np.cos(yaw), np.sin(yaw)
            ahead = lead * np.array([c * cmd[0] - s * cmd[1], s * cmd[0] + c * cmd[1]])
            marker = np.array([[q[0] + ahead[0], q[1] + ahead[1], 0.01]])
            frames.append(renderer.frame(q, marker))
    imageio.mimsave(gif, frames, duration=every * env.control_dt * 1000, loop=0)
    print(f"gif: {gif} ({len(frames)} frames, {Path(gif).stat().st_size} bytes)")


WALKER = Task(
    name="walker",
    title="HexapodWalk-v0 PPO per seed: train wall, greedy speed, falls, targets reached",
    settings=WalkSettings,
    variants=("far", "near"),
    prepare=walk_prepare,
    length=lambda env, s: s.episode_steps,
    record=walk_record,
    figures=walk_figures,
    header=walk_header,
    row=walk_row,
    engine="mjx; mujoco_c* fields under C",
    machine="where each run trained (its gpu field)",
    render=walk_render,
)
JOYSTICK = Task(
    name="joystick",
    title="HexapodJoystick-v0 PPO per seed: train wall, tracking errors, falls",
    settings=JoystickSettings,
    variants=("",),
    prepare=lambda env, params, s, n: params,
    length=lambda env, s: round(s.seconds / env.control_dt),
    record=joystick_record,
    figures=joystick_figures,
    header=joystick_header,
    row=joystick_row,
    engine="mjx: mjx*; MuJoCo C: mujoco_c*",
    machine="training and the mjx eval on the gpu named; the C eval where table runs",
    eval_config={"push_probability": 0.0, "action_noise": 0.0},
    drive=joystick_drive,
)
#: the seeds evaluation of each task, by env id
TASKS: dict[str, Task] = {"HexapodWalk-v0": WALKER, "HexapodJoystick-v0": JOYSTICK}


# ---------------------------------------------------------------------------- the CLI
def _option_fields() -> dict[str, tuple[Any, str]]:
    """Every task's eval options: field name -> (type, help naming the tasks that take it)."""
    kinds: dict[str, Any] = {}
    helps: dict[str, str] = {}
    owners: dict[str, list[str]] = {}
    for env_id, task in TASKS.items():
        for f in dataclasses.fields(task.settings):
            kinds[f.name] = type(f.default)
            helps.setdefault(f.name, f"{f.metadata['help']}; default {f.default}")
            owners.setdefault(f.name, []).append(env_id)
    return {k: (kinds[k], f"{helps[k]} ({', '.join(owners[k])})") for k in kinds}


def _parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(description=(__doc__ or "").splitlines()[0])
    sub = parser.add_subparsers(dest="command", required=True)
    ev = sub.add_parser("eval", help="measure one run (its task from its config)")
    ev.add_argument("run_dir")
    ev.add_argument("--physics", choices=("mjx", "c"), default=None)
    ev.add_argument("--envs", type=int, default=256, help="envs per group")
    ev.add_argument("--seed", type=int, default=123)
    ev.add_argument("--trajectory", metavar="OUT.npz", help="save env 0's path per group")
    for name, (kind, ids) in _option_fields().items():
        flag = "--" + name.replace("_", "-")
        ev.add_argument(flag, dest=name, type=kind, default=None, help=ids)
    sl = sub.add_parser("slim", help="write a run's greedy policy to RUN/policy.npz")
    sl.add_argument("run_dir")
    tb = sub.add_parser("table", help="per-seed records of evaluated runs (one task)")
    tb.add_argument("run_dirs", nargs="+")
    tb.add_argument("--json", metavar="NAME", required=True, help=results_io.HELP)
    tb.add_argument("--machine", default=None, help="where the runs trained and were evaluated")
    rd = sub.add_parser("render", help="draw a trajectory saved by eval --trajectory")
    rd.add_argument("trajectory")
    rd.add_argument("--group", default="default_near")
    rd.add_argument("--gif", metavar="OUT.gif")
    rd.add_argument("--strip", metavar="OUT.png")
    rd.add_argument("--seconds", type=float, help="draw the first SECONDS of the episode")
    dr = sub.add_parser("drive", help="play a command sequence, print it, draw it")
    dr.add_argument("run_dir")
    dr.add_argument("--physics", choices=("mjx", "c"), default=None)
    dr.add_argument("--gif", metavar="OUT.gif", help="draw it (MUJOCO_GL=egl)")
    return parser


def _eval(args: argparse.Namespace) -> None:
    env_id = runner.load_run_config(Path(args.run_dir)).env_id
    task = task_of(env_id)
    own = {f.name for f in dataclasses.fields(task.settings)}
    given = {k: getattr(args, k) for k in _option_fields() if getattr(args, k) is not None}
    foreign = sorted(set(given) - own)
    if foreign:
        flag = "--" + foreign[0].replace("_", "-")
        raise SystemExit(f"{flag} is not an option of {env_id}'s evaluation")
    result, trajectory = evaluate(args.run_dir, args.physics, args.envs, args.seed, **given)
    print(json.dumps(brief(task, result), indent=1))
    out = Path(args.run_dir) / task.eval_file(result["physics"])
    out.write_text(json.dumps(result, indent=2) + "\n")
    if args.trajectory:
        np.savez_compressed(args.trajectory, env_id=np.asarray(env_id), **trajectory)


def main(argv: list[str] | None = None) -> None:
    args = _parser().parse_args(argv)
    if args.command == "eval":
        _eval(args)
    elif args.command == "slim":
        print(f"policy: {runner.save_policy(args.run_dir)}")
    elif args.command == "table":
        task, rows = table(args.run_dirs)
        rec = results_io.record(
            args.json,
            task.title,
            rows,
            description=args.machine or task.machine,
            engine=task.engine,
        )
        rec["machine"]["gpu"] = sorted({r["gpu"] for r in rows if "gpu" in r})
        results_io.write(args.json, rec)
        print(json.dumps(rows, indent=2))
    elif args.command == "render":
        task = task_of(str(np.load(args.trajectory)["env_id"]))
        if task.render is None:
            raise SystemExit(f"render: nothing to draw for {task.name} trajectories")
        task.render(args.trajectory, args)
    else:
        task = task_of(runner.load_run_config(Path(args.run_dir)).env_id)
        if task.drive is None:
            raise SystemExit(f"drive: {task.name} runs take no command sequence")
        task.drive(args.run_dir, args)


if __name__ == "__main__":
    main()
