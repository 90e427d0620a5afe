"""``jaxenvs deploy POLICY --env ID --robot ADDRESS|sim --seconds S``: run an exported
policy on a robot in real time (:mod:`jaxenvs.deploy.loop`)."""

from __future__ import annotations

import argparse
import contextlib
import json
import signal
import subprocess
import sys
import tempfile
from typing import Any

from jaxenvs.cli import checks
from jaxenvs.cli.robot_cmd import terrain_overrides

HELP = "run an exported policy on a robot (tcp://HOST:PORT, or sim) at the control rate"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("policy", metavar="POLICY", help="an exported policy (.onnx or .npz)")
    parser.add_argument("--env", required=True, metavar="ID", help="the task it was trained on")
    parser.add_argument(
        "--robot",
        required=True,
        metavar="ADDRESS|sim",
        help="tcp://HOST:PORT of a robot, or sim: start the simulated robot (jaxenvs robot)",
    )
    parser.add_argument("--seconds", type=float, required=True, help="how long to run")
    parser.add_argument("--latency-ms", type=float, default=0.0, help="sim: message delay")
    parser.add_argument("--jitter-ms", type=float, default=0.0, help="sim: extra uniform delay")
    parser.add_argument("--noise", type=float, default=0.0, help="sim: sensor noise std scale")
    parser.add_argument(
        "--terrain",
        metavar="LEVEL[:TYPE]",
        help="sim, a terrain task: the robot starts on a tile of this level (jaxenvs robot)",
    )
    parser.add_argument("--summary", metavar="FILE", help="write the JSON summary here")
    parser.add_argument("--log", metavar="FILE", help="record sensors and commands (MCAP)")
    parser.add_argument(
        "--command",
        dest="task_input",
        metavar="FILE|-",
        help="the task's input (a target, a joystick command): a script of 'T v1 v2 ...' "
        "lines, or - to type 'v1 v2 ...' lines",
    )
    parser.add_argument(
        "--max-late-ms", type=float, help="stop when a command is this late (default 5 periods)"
    )
    parser.add_argument(
        "--sensor-timeout-ms",
        type=float,
        help="stop after this long without sensors (default 10 periods)",
    )
    parser.add_argument(
        "--key-file",
        metavar="FILE",
        help="prove this key to the robot, and have it prove it back (jaxenvs robot "
        "--key-file; with sim, the simulated robot is keyed with it)",
    )
    parser.add_argument("--seed", type=int, default=0, help="sim: initial state, noise")
    parser.add_argument(
        "--realtime",
        action="store_true",
        help="run the loop (and a sim robot) under SCHED_FIFO (Linux, CAP_SYS_NICE)",
    )


def _start_sim(args: argparse.Namespace) -> subprocess.Popen[str]:
    """``jaxenvs robot`` in another process, on a free loopback port (it prints it)."""
    cmd = [
        sys.executable,
        "-m",
        "jaxenvs",
        "robot",
        args.env,
        "--listen",
        "tcp://127.0.0.1:0",
        "--once",
        "--latency-ms",
        str(args.latency_ms),
        "--jitter-ms",
        str(args.jitter_ms),
        "--noise",
        str(args.noise),
        "--seed",
        str(args.seed),
    ]
    if args.key_file:
        cmd += ["--key-file", args.key_file]
    if args.terrain:
        cmd += ["--terrain", args.terrain]
    errors = tempfile.TemporaryFile("w+")
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=errors, text=True)
    proc.errors = errors  # type: ignore[attr-defined]
    return proc


def _address_of(proc: subprocess.Popen[str]) -> str:
    assert proc.stdout is not None
    line = proc.stdout.readline().strip()
    if not line.startswith("listening on "):
        proc.wait(5)
        proc.errors.seek(0)  # type: ignore[attr-defined]
        last = (proc.errors.read().strip().splitlines() or ["no message"])[-1]  # type: ignore[attr-defined]
        raise ValueError(f"the simulated robot did not start: {last}")
    return line.removeprefix("listening on ")


def _stop(proc: subprocess.Popen[str] | None) -> None:
    if proc is None:
        return
    try:
        proc.wait(2)
    except subprocess.TimeoutExpired:
        proc.terminate()
        proc.wait(2)


def _interrupt(signum: int, frame: Any) -> None:
    raise KeyboardInterrupt


def run(args: argparse.Namespace) -> int:
    checks.float_flag("--seconds", args.seconds, 1e-3, 1e7)
    checks.float_flag("--latency-ms", args.latency_ms, 0.0, 1e4)
    checks.float_flag("--jitter-ms", args.jitter_ms, 0.0, 1e4)
    checks.float_flag("--noise", args.noise, 0.0, 1e3)
    checks.float_flag("--max-late-ms", args.max_late_ms, 0.0, 1e6)
    checks.float_flag("--sensor-timeout-ms", args.sensor_timeout_ms, 0.0, 1e6)
    checks.int_flag("--seed", args.seed, 0)
    from jaxenvs.deploy import auth, loop, simrobot
    from jaxenvs.deploy.commands import CommandInput

    if args.robot != "sim":
        simrobot.parse_address(args.robot)
        if args.latency_ms or args.jitter_ms or args.noise or args.terrain:
            raise ValueError("--latency-ms, --jitter-ms, --noise and --terrain set up --robot sim")
    terrain_overrides(args.env, args.terrain)  # a bad --terrain is refused before the robot starts
    key = auth.read_key(args.key_file) if args.key_file else None
    policy = loop.HostPolicy(args.policy)
    if policy.metadata["env_id"] != args.env:
        raise ValueError(
            f"{args.policy} is a policy of {policy.metadata['env_id']}, not {args.env}"
        )
    commands = CommandInput(args.task_input) if args.task_input else None
    if commands is not None:  # a script of the wrong size fails before anything starts
        from jaxenvs import registry

        shape = getattr(registry.spec(args.env).factory, "task_input_shape", None)
        if shape is not None:
            commands.expect(tuple(shape), args.env)
    previous = signal.signal(signal.SIGTERM, _interrupt)
    proc = _start_sim(args) if args.robot == "sim" else None
    try:
        return _deploy(args, policy, commands, proc, key)
    finally:
        if proc is not None and proc.poll() is None:
            _stop(proc)
        signal.signal(signal.SIGTERM, previous)


def _deploy(args: argparse.Namespace, policy: Any, commands: Any, proc: Any, key: Any) -> int:
    import jaxenvs
    from jaxenvs.deploy import link as link_mod
    from jaxenvs.deploy import loop
    from jaxenvs.deploy.log import LogError, LogWriter
    from jaxenvs.robots.interface import HostTask, LinkError, spec_of

    env = jaxenvs.make(args.env, physics="c")
    # the trained env's fields the loop depends on (a task's deploy_fields, e.g.
    # HexapodJoystick-v0's action_delay_max and action_filter) from the policy's metadata
    trained = json.loads(policy.metadata.get("env_config", "{}"))
    shaping = {k: trained[k] for k in getattr(env, "deploy_fields", ()) if k in trained}
    if shaping:
        env = jaxenvs.make(args.env, physics="c", **shaping)
    if str(env.observation_size) != policy.metadata.get("observation_size"):
        raise ValueError(
            f"the policy takes {policy.metadata.get('observation_size')} observation values, "
            f"{args.env} gives {env.observation_size}"
        )
    if abs(float(policy.metadata["control_dt"]) - env.control_dt) > 1e-9:
        raise ValueError(f"the policy's control period differs from {args.env}'s")
    host = HostTask(env, args.seed)
    spec = spec_of(env, args.env)
    dt_ms = env.control_dt * 1e3
    opts = loop.LoopOptions(
        seconds=args.seconds,
        max_late_ms=args.max_late_ms if args.max_late_ms is not None else 5 * dt_ms,
        sensor_timeout_ms=(
            args.sensor_timeout_ms if args.sensor_timeout_ms is not None else 10 * dt_ms
        ),
    )
    address = _address_of(proc) if proc is not None else args.robot
    robot = link_mod.TcpRobot(address, key=key)
    log = LogWriter(args.log) if args.log else None
    try:
        rec = _drive(robot, spec, host, env, policy, opts, log, commands, args.realtime)
    except (LinkError, LogError) as err:
        rec = loop.Record(dt=env.control_dt, error=str(err))
    except BaseException:
        if log is not None:
            with contextlib.suppress(LogError):  # the first failure is the one to tell
                log.close()
        raise
    finally:
        robot.close()
    s = loop.summary(rec, robot, policy, args.env, args.seconds)
    if log is not None:
        log_error = _finish_log(log, s, rec)
        if log_error and not rec.error:
            rec.error = s["error"] = log_error
    summary_error = _write_summary(args.summary, s)
    _stop(proc)
    if rec.error or summary_error:
        error = rec.error or summary_error
        print(f"jaxenvs deploy: error: {error} (after {rec.steps} steps)", file=sys.stderr)
        return 1
    print(loop.one_line(s))
    return 0


def _finish_log(log: Any, s: dict, rec: Any) -> str | None:
    """Write the summary and the end into the log and finish it; why it failed, if it
    did (the file then holds every whole record written before)."""
    from jaxenvs.deploy.log import LogError

    try:
        log.write("/deploy/summary", s)
        log.write("/deploy/event", {"event": "end", "reason": rec.error or "done"})
        log.close()
    except LogError as err:
        return str(err)
    return log.failed or None


def _write_summary(path: str | None, s: dict) -> str | None:
    """Write the JSON summary to ``path`` (atomically); why it failed, if it did."""
    if not path:
        return None
    from jaxenvs import files

    try:
        files.write_text(path, json.dumps(s, indent=2) + "\n")
    except OSError as err:
        return f"cannot write the summary {path}: {err.strerror or err}"
    return None


def _drive(
    robot: Any,
    spec: Any,
    host: Any,
    env: Any,
    policy: Any,
    opts: Any,
    log: Any,
    commands: Any,
    realtime: bool,
) -> Any:
    import numpy as np

    from jaxenvs.deploy import loop
    from jaxenvs.deploy.commands import input_range

    model = env.sim.physics_mj_model
    truth = {
        "qpos": model.qpos0.copy(),
        "qvel": np.zeros(model.nv),
        "mocap_pos": model.body_pos[model.body_mocapid >= 0].copy(),
    }
    task_shape = host.warm(spec.sizes(), truth)  # compile before the robot's clock starts
    if commands is not None:
        commands.expect(task_shape, spec.env_id, input_range(env))
    theirs = robot.connect()
    spec.check_matches(theirs)  # sensors, actuators and their limits, control period
    if robot.privileged:
        robot.set_state_sizes(model.nq, model.nv, model.nmocap)
    elif host.needs_input and commands is None:
        raise ValueError(
            f"{spec.env_id} needs a task input (a target, a command) the robot does not "
            "send: give --command FILE|-"
        )
    priority = loop.raise_priority() if realtime else "normal priority"
    print(
        f"running {spec.env_id} on {robot.address} for {opts.seconds:g} s, {priority}", flush=True
    )
    if log is not None:
        log.write("/robot/hello", {"privileged": robot.privileged, **theirs.to_json()})
    return loop.run(robot, host, policy, opts, log, commands)
