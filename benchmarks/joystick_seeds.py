"""HexapodJoystick-v0 policies per seed: velocity tracking errors and falls, on three benches.

``eval`` drives a trained run's greedy policy (``jaxenvs train HexapodJoystick-v0 ...``) in
one batch of ``2 x --envs`` envs, each for one episode of ``--seconds`` (20 s = 400
control steps) with the command redrawn on the task's schedule (every 5 s) over the run's
full command ranges (zero with the task's probability), under the task's default physics
params (``default``) and under params drawn by ``env.sample_params``, one draw per env
(``randomized``: mass and inertia x0.8-1.2, foot friction x0.7-1.3, servo kp x0.8-1.2,
joint damping x0.7-1.3). Per group:

* ``tracking_error_lin``: the RMS over the env-steps while up of |command - velocity| in
  the horizontal plane (m/s), the velocity being the body's mean velocity over the control
  step in its heading frame (the task's ``lin_error`` metric);
* ``tracking_error_yaw``: the same of the yaw rate (rad/s; ``yaw_error``);
* ``*_settled``: the same without the first second after each command change;
* ``fell_fraction``: the fraction of envs that fell within the episode.

A fall is the task's DEFAULT termination (``JoystickConfig()``: body below 0.06 m or tilted
more than ~45 degrees), whatever termination the run trained with; pushes are off; the
run's observation noise, action delay (``action_delay_max``: each env's drawn at reset) and
sensor biases are kept, so a run trained for the robot's link is measured with them.
``--physics c`` runs it on MuJoCo's C engine (CPU; set ``JAX_PLATFORMS=cpu``).

``eval`` writes its figures to ``RUN/joystick_eval_mjx.json`` (or ``_c.json``); ``table``
collects them, with each run's summary.json, into one record per run
(``benchmarks/results/ppo_joystick_seeds_h100.json``); ``slim`` writes a run's greedy
policy to ``RUN/policy.npz``, which ``eval`` reads where the full ``checkpoint.npz`` was not
kept (``walker_seeds.py`` says more).

    python benchmarks/joystick_seeds.py slim RUN
    python benchmarks/joystick_seeds.py eval RUN
    JAX_PLATFORMS=cpu python benchmarks/joystick_seeds.py eval RUN --physics c --envs 128
    python benchmarks/joystick_seeds.py table RUN0 RUN1 RUN2 --json ppo_joystick_seeds_h100
    MUJOCO_GL=egl JAX_PLATFORMS=cpu python benchmarks/joystick_seeds.py drive RUN --physics c \\
        --gif benchmarks/images/hexapod_joystick.gif

``drive`` plays a fixed command sequence (:data:`SEQUENCE`: forward, forward while
turning, sideways, backwards, turning on the spot, standing) through the task's
``with_command`` and prints the mean velocity under each command.
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
from walker_seeds import load_policy, slim

from jaxenvs.run import runner
from jaxenvs.tasks.hexapod_joystick import HexapodJoystick, JoystickConfig

GROUPS = ("default", "randomized")
EVAL_FILE = "joystick_eval_{}.json"  # .format(physics)
#: (engine, record field, group) of each bench in a ``table`` record
BENCHES = (
    ("mjx", "mjx", "default"),
    ("mjx", "mjx_randomized", "randomized"),
    ("c", "mujoco_c", "default"),
    ("c", "mujoco_c_randomized", "randomized"),
)
FIGURES = (
    "tracking_error_lin",
    "tracking_error_yaw",
    "fell_fraction",
    "tracking_error_lin_settled",
    "tracking_error_yaw_settled",
)


def eval_env(run_dir: str, physics: str | None) -> tuple[HexapodJoystick, Any]:
    """The run's env with the task's default termination and no pushes, and the run's
    greedy policy."""
    env_id, env, act = load_policy(run_dir, physics)
    if env_id != "HexapodJoystick-v0" or not isinstance(env, HexapodJoystick):
        raise SystemExit(f"{run_dir} trained {env_id}, not HexapodJoystick-v0")
    task = JoystickConfig()
    config = dataclasses.replace(
        env.config,
        min_height=task.min_height,
        min_upright=task.min_upright,
        push_probability=0.0,
        action_noise=0.0,
    )
    return HexapodJoystick(config), act


def rollout(env: HexapodJoystick, act: Any, params: Any, key: jax.Array, steps: int) -> Any:
    """Step every env of ``params`` (leading axis) for ``steps`` control steps without
    resets; per step: (lin_error, yaw_error, since, up before, up after, height low), and
    env 0's of each half: qpos, command, velocity."""
    n = jax.tree.leaves(params)[0].shape[0]
    state = jax.vmap(env.reset)(jax.random.split(key, n), params)

    def body(carry, _):  # type: ignore[no-untyped-def]
        s, up = carry
        a = jax.vmap(act)(s.obs, jax.random.split(s.key[0], n))
        prev = s.data
        s = jax.vmap(env.step)(s, a, params)
        up_after = up & ~s.terminated
        low = s.data.qpos[:, 2] < env.config.min_height
        vel = jax.vmap(env.velocity)(prev, s.data)
        out = (s.info["lin_error"], s.info["yaw_error"], s.extras.since, up, up_after, low)
        show = (s.data.qpos[0 :: n // 2], s.extras.command[0 :: n // 2], vel[0 :: n // 2])
        return (s, up_after), (out, show)

    _, (out, show) = jax.lax.scan(body, (state, jnp.ones(n, bool)), None, length=steps)
    return out, show


def group_figures(
    lin: np.ndarray,
    yaw: np.ndarray,
    since: np.ndarray,
    up: np.ndarray,
    after: np.ndarray,
    settle: int,
) -> dict[str, float]:
    """The figures of one group (module docstring) from per-step arrays (steps, envs)."""

    def rms(err: np.ndarray, mask: np.ndarray) -> float:
        # a fallen env keeps stepping and under C can blow up: select, do not multiply
        return float(np.sqrt(np.where(mask, err * err, 0.0).sum() / max(mask.sum(), 1)))

    settled = up & (since >= settle)
    return {
        "tracking_error_lin": rms(lin, up),
        "tracking_error_yaw": rms(yaw, up),
        "fell_fraction": float(1.0 - after[-1].mean()),
        "tracking_error_lin_settled": rms(lin, settled),
        "tracking_error_yaw_settled": rms(yaw, settled),
    }


def evaluate(
    run_dir: str,
    physics: str | None = None,
    envs: int = 256,
    seconds: float = 20.0,
    seed: int = 123,
) -> tuple[dict[str, Any], dict[str, np.ndarray]]:
    """The figures of one run (module docstring) and env 0's poses, commands and
    velocities of each group."""
    env, act = eval_env(run_dir, physics)
    n, steps = envs, round(seconds / env.control_dt)
    params_key, reset_key = jax.random.split(jax.random.key(seed))
    base = env.default_params
    drawn = jax.vmap(env.sample_params)(jax.random.split(params_key, n))
    default = jax.tree.map(lambda x: jnp.broadcast_to(x, (n, *x.shape)), base)
    params = jax.tree.map(lambda *xs: jnp.concatenate(xs), default, drawn)  # GROUPS' order

    start = time.perf_counter()
    run = jax.jit(rollout, static_argnums=(0, 1, 4))
    out, show = jax.device_get(run(env, act, params, reset_key, steps))
    seconds_wall = time.perf_counter() - start
    lin, yaw, since, up, after, low = (np.asarray(x) for x in out)
    settle = round(1.0 / env.control_dt)
    result: dict[str, Any] = {
        "physics": env.physics,
        "device": jax.devices()[0].device_kind,
        "envs_per_group": n,
        "steps": steps,
        "seconds": steps * env.control_dt,
        "command_interval_s": env.config.command_interval * env.control_dt,
        "command_ranges": {
            "vx": list(env.config.vx_range),
            "vy": list(env.config.vy_range),
            "yaw": list(env.config.yaw_range),
            "zero_probability": env.config.zero_probability,
        },
        "settle_s": settle * env.control_dt,
        "action_delay_max": env.config.action_delay_max,
        "sensor_bias": {"joint": env.config.joint_bias, "gyro": env.config.gyro_bias},
        "wall_seconds": round(seconds_wall, 2),  # compile included
    }
    for g, name in enumerate(GROUPS):
        cols = slice(g * n, (g + 1) * n)
        stats = group_figures(
            lin[:, cols], yaw[:, cols], since[:, cols], up[:, cols], after[:, cols], settle
        )
        fell = ~after[-1, cols]
        fall_step = (~after[:, cols]).argmax(0)[fell]
        stats["falls_by_height"] = int(low[fall_step, np.flatnonzero(fell) + g * n].sum())
        stats["fall_seconds"] = sorted(round(float(t + 1) * env.control_dt, 2) for t in fall_step)
        result[name] = stats
    qpos, command, velocity = (np.asarray(x) for x in show)
    trajectory = {
        f"{name}_{field}": x[:, g]
        for g, name in enumerate(GROUPS)
        for field, x in (("qpos", qpos), ("command", command), ("velocity", velocity))
    }
    return result, trajectory


#: the command sequence ``drive`` plays: (seconds, (vx m/s, vy m/s, yaw rate rad/s))
SEQUENCE = (
    (4.0, (0.3, 0.0, 0.0)),
    (4.0, (0.2, 0.0, 0.6)),
    (3.0, (0.0, -0.2, 0.0)),
    (3.0, (-0.2, 0.0, 0.0)),
    (3.0, (0.0, 0.0, -0.8)),
    (2.0, (0.0, 0.0, 0.0)),
)


def drive(run_dir: str, physics: str | None, seed: int = 0) -> dict[str, np.ndarray]:
    """Play :data:`SEQUENCE` with the run's greedy policy in one env (default physics, no
    pushes): per step the pose, the command and the velocity."""
    env, act = eval_env(run_dir, physics)
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

    qpos, velocity, fell = (np.asarray(x) for x in play(jax.random.key(seed), commands))
    return {"qpos": qpos, "command": commands, "velocity": velocity, "fell": fell}


def render_drive(path: dict[str, np.ndarray], gif: str, lead: float = 1.5, every: int = 3) -> None:
    """An animated GIF of a ``drive`` (every ``every`` control steps); the red marker sits
    where the command would take the body in ``lead`` seconds (vx, vy in its heading)."""
    import imageio.v2 as imageio

    from jaxenvs import make
    from jaxenvs import render as rendering
    from jaxenvs.tasks.hexapod_joystick import heading

    env = make("HexapodJoystick-v0", physics="c")
    frames = []
    with rendering.Renderer(env, 240, 180, None) as renderer:
        renderer.model.vis.headlight.ambient[:] = 0.35
        renderer.model.vis.headlight.diffuse[:] = 0.55
        for q, cmd in zip(path["qpos"][::every], path["command"][::every], strict=True):
            yaw = float(heading(jnp.asarray(q[3:7])))
            c, s = np.cos(yaw), np.sin(yaw)
            ahead = lead * np.array([c * cmd[0] - s * cmd[1], s * cmd[0] + c * cmd[1]])
            marker = np.array([[q[0] + ahead[0], q[1] + ahead[1], 0.01]])
            frames.append(renderer.frame(q, marker))
    imageio.mimsave(gif, frames, duration=every * env.control_dt * 1000, loop=0)
    print(f"gif: {gif} ({len(frames)} frames, {Path(gif).stat().st_size} bytes)")


def table(run_dirs: list[str]) -> list[dict[str, Any]]:
    """One record per run (seed) from its summary.json, config.yaml and eval files."""
    rows = []
    for run_dir in run_dirs:
        run = Path(run_dir)
        summary = json.loads((run / runner.SUMMARY_FILE).read_text())
        resolved = runner.load_run_config(run)
        row: dict[str, Any] = {
            "seed": resolved.train.seed,
            "run": run.name,
            "train_seconds": summary["wall_seconds"],
            # the first chunk's wall: mostly compile (short where the compile cache was warm)
            "first_chunk_seconds": float(
                runner.read_progress(run / runner.PROGRESS_FILE)[0]["wall_seconds"]
            ),
            "env_steps": summary["env_steps"],
            "eval_mean_return": summary["eval_mean_return"],
            # what the run trained (and was evaluated) with for the robot's link
            "action_delay_max": resolved.env.action_delay_max,
            "sensor_bias": {"joint": resolved.env.joint_bias, "gyro": resolved.env.gyro_bias},
            # the metrics the critic saw besides the observation (PPO's critic_info)
            "critic_info": list(resolved.agent.critic_info),
        }
        for physics, field, group in BENCHES:
            path = run / EVAL_FILE.format(physics)
            if not path.exists():
                continue
            ev = json.loads(path.read_text())
            if physics == "mjx":
                row["gpu"] = ev["device"]
            row[field] = {k: round(ev[group][k], 4) for k in FIGURES}
        rows.append(row)
    return sorted(rows, key=lambda r: r["seed"])


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=(__doc__ or "").splitlines()[0])
    sub = parser.add_subparsers(dest="command", required=True)
    ev = sub.add_parser("eval", help="measure one run")
    ev.add_argument("run_dir")
    ev.add_argument("--physics", choices=("mjx", "c"), default=None)
    ev.add_argument("--envs", type=int, default=256, help="envs per group")
    ev.add_argument("--seconds", type=float, default=20.0, help="episode length (s)")
    ev.add_argument("--seed", type=int, default=123)
    ev.add_argument("--trajectory", metavar="OUT.npz", help="save env 0's poses per group")
    sl = sub.add_parser("slim", help="write a run's greedy policy to RUN/policy.npz")
    sl.add_argument("run_dir")
    dr = sub.add_parser("drive", help="play a command sequence, print it, draw it")
    dr.add_argument("run_dir")
    dr.add_argument("--physics", choices=("mjx", "c"), default=None)
    dr.add_argument("--gif", metavar="OUT.gif", help="draw it (MUJOCO_GL=egl)")
    tb = sub.add_parser("table", help="per-seed records of evaluated runs")
    tb.add_argument("run_dirs", nargs="+")
    tb.add_argument("--json", metavar="NAME", required=True, help=results_io.HELP)
    tb.add_argument(
        "--machine",
        default="training and the mjx eval on the gpu named; the C eval where table runs",
        help="where the runs trained and were evaluated (the record's machine description)",
    )
    args = parser.parse_args(argv)

    if args.command == "eval":
        result, trajectory = evaluate(
            args.run_dir, args.physics, args.envs, args.seconds, args.seed
        )
        brief = {k: v for k, v in result.items() if k not in GROUPS}
        for name in GROUPS:
            brief[name] = {k: round(result[name][k], 4) for k in FIGURES}
        print(json.dumps(brief, indent=1))
        out = Path(args.run_dir) / EVAL_FILE.format(result["physics"])
        out.write_text(json.dumps(result, indent=2) + "\n")
        if args.trajectory:
            np.savez_compressed(args.trajectory, **trajectory)
    elif args.command == "drive":
        path = drive(args.run_dir, args.physics)
        start = 0
        for seconds, cmd in SEQUENCE:
            end = start + round(seconds / 0.05)
            v = path["velocity"][start + 20 : end].mean(0)  # after the first second
            print(f"command {cmd}: mean velocity {tuple(round(float(x), 3) for x in v)}")
            start = end
        print(f"fell: {bool(path['fell'].any())}")
        if args.gif:
            render_drive(path, args.gif)
    elif args.command == "slim":
        print(f"policy: {slim(args.run_dir)}")
    else:
        rows = table(args.run_dirs)
        title = "HexapodJoystick-v0 PPO per seed: train wall, tracking errors, falls"
        rec = results_io.record(
            args.json,
            title,
            rows,
            description=args.machine,
            engine="mjx: mjx*; MuJoCo C: mujoco_c*",
        )
        rec["machine"]["gpu"] = sorted({r["gpu"] for r in rows if "gpu" in r})
        results_io.write(args.json, rec)
        print(json.dumps(rows, indent=2))


if __name__ == "__main__":
    main()
