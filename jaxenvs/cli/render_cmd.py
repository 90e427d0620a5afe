"""``jaxenvs render``: a video of one env, with random actions or a trained policy.

``jaxenvs render CartpoleSwingup-v0 --out swingup.mp4 --steps 300`` rolls out one env of a
batched (auto-resetting) env in a single jitted scan, then renders that trajectory
headlessly with :mod:`jaxenvs.render` and writes the video atomically. ``--policy RUN_DIR``
acts with the greedy policy of a run written by ``jaxenvs train`` (through
``jaxenvs.run.runner.load_policy``) on the run's own env config. ``--log FILE`` renders
the run a ``jaxenvs deploy --log`` recorded instead (its poses from the robot's ground
truth, or from its joint encoders' readings; :mod:`jaxenvs.deploy.log`).
"""

from __future__ import annotations

import argparse
from collections.abc import Callable
from typing import Any

from jaxenvs.cli import checks, engine_args
from jaxenvs.core.xla import jit

HELP = "render a video of an env with random actions or a trained policy (--policy RUN_DIR)"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "env_id", metavar="ID", nargs="?", help="registered env id (see `jaxenvs list`)"
    )
    parser.add_argument("--out", required=True, help="output video (.mp4 or .gif)")
    parser.add_argument("--policy", metavar="RUN_DIR", help="act with this training run")
    parser.add_argument("--log", metavar="FILE", help="render a jaxenvs deploy log (MCAP)")
    parser.add_argument("--steps", type=int, default=300, help="control steps (default 300)")
    parser.add_argument("--seed", type=int, default=0, help="PRNG seed (default 0)")
    parser.add_argument("--width", type=int, default=640, help="frame width (default 640)")
    parser.add_argument("--height", type=int, default=480, help="frame height (default 480)")
    parser.add_argument("--camera", help="camera name or index (default: the task's)")
    parser.add_argument("--fps", type=float, help="video frame rate (default: real time)")
    engine_args.add(parser)


ActFn = Callable[[Any, Any], Any]


def _policy(run_dir: str, env_id: str, physics: str | None = None) -> tuple[Any, ActFn]:
    """The run's env and greedy ``act_fn(obs, key)``; the run must be of ``env_id``."""
    try:
        from jaxenvs.run import runner
    except ImportError as err:
        raise ValueError(f"--policy needs jaxenvs.run.runner, which failed: {err}") from err
    loaded = runner.load_policy(run_dir, physics)
    run_env_id, env, act_fn = loaded if len(loaded) == 3 else (loaded[0], None, loaded[-1])
    if run_env_id != env_id:
        raise ValueError(f"{run_dir} is a run of {run_env_id}, not {env_id}")
    return env, act_fn


def _random_act(env: Any) -> ActFn:
    import jax

    def act(obs: Any, key: Any) -> Any:
        del obs
        if env.discrete:
            return jax.random.randint(key, (), 0, env.action_size)
        return jax.random.uniform(key, (env.action_size,), minval=-1.0, maxval=1.0)

    return act


def rollout(env: Any, act_fn: ActFn, steps: int, seed: int) -> Any:
    """States (leading time axis, reset state first) of one auto-resetting env."""
    import jax

    from jaxenvs.core import BatchedEnv

    benv = BatchedEnv(env, 1)

    def run(key: jax.Array) -> Any:
        reset_key, act_key = jax.random.split(key)
        first = benv.reset(reset_key)

        def body(state: Any, k: jax.Array) -> tuple[Any, Any]:
            action = jax.vmap(act_fn)(state.obs, k[None])
            state = benv.step(state, action)
            return state, state

        _, states = jax.lax.scan(body, first, jax.random.split(act_key, steps))
        both = jax.tree.map(lambda a, b: jax.numpy.concatenate([a[None], b]), first, states)
        return jax.tree.map(lambda x: x[:, 0], both)

    return jit(run)(jax.random.key(seed))


def _check_even_size(args: argparse.Namespace) -> None:
    """An .mp4 (H.264 in yuv420p) needs an even frame size: refuse an odd flag at once."""
    from jaxenvs.cli import UserError

    if not args.out.lower().endswith(".mp4"):
        return
    for flag, value in (("--width", args.width), ("--height", args.height)):
        if value % 2:
            raise UserError(f"{flag} must be even for an .mp4 video (H.264, yuv420p), got {value}")


def run(args: argparse.Namespace) -> int:
    import jaxenvs
    from jaxenvs import render

    checks.int_flag("--steps", args.steps, 1, 10**6)
    checks.int_flag("--seed", args.seed, 0)
    checks.int_flag("--width", args.width, 1, 8192)
    checks.int_flag("--height", args.height, 1, 8192)
    checks.float_flag("--fps", args.fps, 1e-3, 1e4)
    render.check_video_path(args.out)
    _check_even_size(args)
    camera = int(args.camera) if args.camera is not None and args.camera.isdigit() else args.camera
    if args.log:
        return _render_log(args, camera)
    if args.env_id is None:
        raise ValueError("give an env ID (or --log FILE)")
    physics = {} if args.physics is None else {"physics": args.physics}
    env = jaxenvs.make(args.env_id, **physics)
    if args.policy:
        run_env, act_fn = _policy(args.policy, args.env_id, args.physics)
        env = run_env or env
    else:
        act_fn = _random_act(env)
    render.Renderer(env, args.width, args.height, camera).close()  # bad camera/size: fail now
    render.select_gl_backend()  # fail before the rollout when nothing can render
    engine_args.say(env)
    states = rollout(env, act_fn, args.steps, args.seed)
    # drawn as they are encoded: a long video is never held whole
    frames = render.iter_frames(env, states, width=args.width, height=args.height, camera=camera)
    fps = args.fps if args.fps is not None else 1.0 / env.control_dt
    path = render.write_video(frames, args.out, fps=fps)
    print(f"wrote {path} ({states.time.shape[0]} frames, {fps:g} fps)")
    return 0


def _render_log(args: argparse.Namespace, camera: str | int | None) -> int:
    """The video of a deploy log: one frame per logged pose, at the control rate."""
    import jaxenvs
    from jaxenvs import render
    from jaxenvs.deploy.log import poses, read_log

    if args.policy:
        raise ValueError("--log renders a recorded run: give no --policy")
    messages = read_log(args.log)
    hello = messages["/robot/hello"]
    if not hello:
        raise ValueError(f"{args.log}: no /robot/hello message (not a jaxenvs deploy log)")
    env_id = hello[0].get("env_id")
    if not isinstance(env_id, str):
        raise ValueError(f"{args.log}: its /robot/hello names no env id (a damaged log)")
    if args.env_id not in (None, env_id):
        raise ValueError(f"{args.log} is a run of {env_id}, not {args.env_id}")
    env = jaxenvs.make(env_id, physics="c")
    robot = env.robot  # type: ignore[union-attr]
    encoders = {n: robot.joints[robot.sensors[n].joint].qpos for n in robot.encoders}
    qpos, mocap = poses(messages, env.sim.mj_model, encoders)
    fps = args.fps if args.fps is not None else 1.0 / env.control_dt
    with render.Renderer(env, args.width, args.height, camera) as renderer:
        # drawn as they are encoded, as a rollout's video is
        frames = (
            renderer.frame(q, None if mocap is None else mocap[t]) for t, q in enumerate(qpos)
        )
        path = render.write_video(frames, args.out, fps=fps)
    print(f"wrote {path} ({len(qpos)} frames of {args.log}, {fps:g} fps)")
    return 0
