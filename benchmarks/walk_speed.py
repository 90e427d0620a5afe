"""Forward speed of a trained HexapodWalk-v0 policy: metres per second toward the target.

Loads the greedy policy of a run directory (``jaxenvs train HexapodWalk-v0 ...``), places
every target ``--target-distance`` metres away (far enough that no env reaches it within
``--steps`` control steps), and averages the task's ``progress`` metric (decrease of the
body-target distance per second) over all envs and steps while the env is still up.
Also reports the fraction of envs that fell.

    python benchmarks/walk_speed.py runs/HexapodWalk-v0-ppo-... --envs 256 --steps 200 \
        --trajectory walk.npz
    python benchmarks/walk_speed.py --render walk.npz --video walk.mp4   # where GL works

``--trajectory`` keeps env 0's poses (``qpos``, target) so that a machine without a GL
backend (a GPU host, say) can measure and another can render the video.
"""

from __future__ import annotations

import argparse
import json

import jax
import jax.numpy as jnp
import numpy as np

import jaxenvs
from jaxenvs.agents import runner
from jaxenvs.tasks.hexapod import quat_to_mat


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=(__doc__ or "").splitlines()[0])
    parser.add_argument("run_dir", nargs="?")
    parser.add_argument("--envs", type=int, default=256)
    parser.add_argument("--steps", type=int, default=200, help="control steps (0.05 s each)")
    parser.add_argument("--target-distance", type=float, default=50.0)
    parser.add_argument("--seed", type=int, default=123)
    parser.add_argument("--trajectory", metavar="OUT.npz", help="save env 0's poses here")
    parser.add_argument("--render", metavar="IN.npz", help="render a saved trajectory")
    parser.add_argument("--video", metavar="OUT.mp4", help="with --render: the video file")
    args = parser.parse_args(argv)
    if args.render:
        render(args.render, args.video or "walk.mp4")
        return
    if not args.run_dir:
        parser.error("give a run directory (or --render FILE.npz)")

    env_id, _, act = runner.load_policy(args.run_dir)
    if env_id != "HexapodWalk-v0":
        raise SystemExit(f"{args.run_dir} trained {env_id}, not HexapodWalk-v0")
    d = args.target_distance
    env = jaxenvs.make(env_id, target_distance=(d, d))

    @jax.jit
    def measure(key: jax.Array) -> dict[str, jax.Array]:
        reset_key, act_key = jax.random.split(key)
        state = jax.vmap(env.reset)(jax.random.split(reset_key, args.envs))

        def body(carry, k):  # type: ignore[no-untyped-def]
            s, up = carry
            a = jax.vmap(act)(s.obs, jax.random.split(k, args.envs))
            s = jax.vmap(env.step)(s, a)
            progress = jnp.where(up, s.info["progress"], 0.0)
            body_up_z = jax.vmap(quat_to_mat)(s.data.qpos[:, 3:7])[:, 2, 2]  # the task's up-axis z
            upright = jnp.where(up, body_up_z, 0.0)
            pose = (s.data.qpos[0], s.data.mocap_pos[0], s.data.mocap_quat[0])
            return (s, up & ~s.terminated), (progress, upright, up, pose)

        keys = jax.random.split(act_key, args.steps)
        (_, up), (progress, upright, alive, pose) = jax.lax.scan(
            body, (state, jnp.ones(args.envs, bool)), keys
        )
        return pose, {
            "speed_m_per_s": progress.sum() / jnp.maximum(alive.sum(), 1),
            "speed_per_env_min": (progress.sum(0) / jnp.maximum(alive.sum(0), 1)).min(),
            "fell_fraction": 1.0 - up.mean(),
            "mean_upright": upright.sum() / jnp.maximum(alive.sum(), 1),
        }

    pose, stats = jax.device_get(measure(jax.random.key(args.seed)))
    out = {k: float(v) for k, v in stats.items()}
    if args.trajectory:
        qpos, mocap_pos, mocap_quat = (np.asarray(x) for x in pose)
        np.savez(args.trajectory, qpos=qpos, mocap_pos=mocap_pos, mocap_quat=mocap_quat)
    out.update(envs=args.envs, steps=args.steps, seconds=args.steps * env.control_dt)
    print(json.dumps(out, indent=2))


def render(trajectory: str, video: str) -> None:
    """Render a trajectory saved by ``--trajectory`` to ``video`` (one frame per step)."""
    from jaxenvs import render as rendering

    env = jaxenvs.make("HexapodWalk-v0")
    pose = np.load(trajectory)
    with rendering.Renderer(env, 480, 360, None) as renderer:
        frames = [
            renderer.frame(q, m, mq)
            for q, m, mq in zip(pose["qpos"], pose["mocap_pos"], pose["mocap_quat"], strict=True)
        ]
    path = rendering.write_video(np.stack(frames), video, fps=1 / env.control_dt)
    print(f"video: {path}")


if __name__ == "__main__":
    main()
