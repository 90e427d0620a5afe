"""``jaxenvs deploy`` and ``jaxenvs robot``: the real-time loop on CartPole through the
simulated robot, each failure mode ending in a hold, one line, a non-zero status and a
readable log within about a second, and the log -> video path.

The policy is a PD controller exported as a one-layer ``.npz`` policy (push right when
``0.1 x + 0.2 x' + theta + 0.3 theta' > 0``): no training in the default tier.
"""

from __future__ import annotations

import json
import os
import signal
import socket
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pytest
from pd_policy import PD_GAINS, pd_policy

from jaxenvs import cli
from jaxenvs.deploy import wire
from jaxenvs.deploy.export import npz_bytes
from jaxenvs.deploy.log import read_log
from jaxenvs.deploy.runtime import FORMAT, FORMAT_VERSION, NumpyPolicy

ROOT = Path(__file__).resolve().parents[2]


def _env() -> dict[str, str]:
    return {**os.environ, "PYTHONPATH": str(ROOT), "MUJOCO_GL": "egl"}


def _jaxenvs(*args: str, **kw) -> subprocess.Popen[str]:
    argv = [sys.executable, "-m", "jaxenvs", *args]
    return subprocess.Popen(
        argv, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=_env(), **kw
    )


def _until_running(proc: subprocess.Popen[str]) -> None:
    """Read the deploy's stdout up to its 'running ...' line (the loop has started)."""
    assert proc.stdout is not None
    line = proc.stdout.readline()
    assert line.startswith("running "), (line, proc.stderr.read() if proc.stderr else "")


def _hold_time(log: Path) -> float:
    """The wall-clock time (s) at which the log recorded the loop's hold."""
    from mcap.reader import NonSeekingReader

    with open(log, "rb") as f:
        for _, channel, message in NonSeekingReader(f).iter_messages(log_time_order=False):
            if channel.topic == "/deploy/event" and json.loads(message.data)["event"] == "hold":
                return message.log_time / 1e9
    raise AssertionError(f"{log} records no hold")


def _failed_fast(
    proc: subprocess.Popen[str], since: float, cause: str, log: Path, ran: bool = True
) -> None:
    """Hold within ~1 s of ``since`` (a ``time.time()``; the hold's time is the log's own
    stamp) and exit non-zero within a few seconds (process teardown, slower on a loaded
    machine) with one line naming ``cause``; a readable log that ends in a hold (holding the
    commands sent, when the loop ``ran``)."""
    _, err = proc.communicate(timeout=10)
    exited = time.time() - since
    assert proc.returncode == 1, err
    lines = err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("jaxenvs deploy: error:"), err
    assert cause in lines[0], lines[0]
    held = _hold_time(log) - since
    assert held < 1.5, f"held {held:.2f} s after the failure"
    assert exited < 5.0, f"the process exited {exited:.2f} s after the failure"
    messages = read_log(log)
    assert messages["/robot/hello"] and bool(messages["/deploy/command"]) == ran
    assert messages["/deploy/event"][0] == {
        "event": "hold",
        "reason": lines[0].split(": ", 2)[2].split(" (after")[0],
    }
    assert messages["/deploy/summary"][0]["error"]


def test_deploy_cartpole_through_the_simulated_robot(tmp_path, capsys):
    """About 2 s of CartPole through ``--robot sim``: the summary's fields present and sane,
    no fall, and the log renders to a video."""
    policy, summary, log = pd_policy(tmp_path / "pd.npz"), tmp_path / "s.json", tmp_path / "l.mcap"
    proc = _jaxenvs(
        "deploy",
        str(policy),
        "--env",
        "CartPole-v0",
        "--robot",
        "sim",
        "--seconds",
        "2",
        "--summary",
        str(summary),
        "--log",
        str(log),
    )
    out, err = proc.communicate(timeout=60)
    assert proc.returncode == 0, err
    assert out.strip().splitlines()[-1].startswith("CartPole-v0: 100 steps")
    s = json.loads(summary.read_text())
    assert s["steps"] == 100 and s["terminated"] is False and s["error"] is None
    assert 95 <= s["return"] <= 100  # +1 per control step seen as ground truth
    assert s["period_ms_mean"] == pytest.approx(20.0, abs=0.5)
    assert 20.0 <= s["period_ms_p99"] < 60.0 and 0 <= s["deadline_misses"] <= 10
    assert 0 < s["round_trip_ms_p50"] < 60.0 and s["bad_messages"] == {}
    messages = read_log(log)
    commands = messages["/deploy/command"]
    assert len(commands) == 100 and [c["step"] for c in commands] == list(range(100))
    assert len(messages["/robot/state"]) >= 95 and messages["/deploy/summary"][0] == s
    video = tmp_path / "run.mp4"
    argv = ["render", "--log", str(log), "--out", str(video), "--width", "160", "--height", "120"]
    assert cli.main(argv) == 0
    frames = f"{len(messages['/robot/state'])} frames"
    assert video.stat().st_size > 1000 and frames in capsys.readouterr().out


@pytest.mark.full
def test_deploy_reacher_takes_its_target_from_the_ground_truth(tmp_path):
    """Reacher's observation needs the target: the loop waits for the simulated robot's
    first ground truth and acts on it; the return is the task's (negative distances)."""
    meta = {
        "format": FORMAT,
        "format_version": FORMAT_VERSION,
        "env_id": "Reacher-v0",
        "observation_size": "10",
        "action_size": "2",
        "discrete": "0",
        "control_dt": "0.02",
        "activation": "tanh",
    }
    kernel = np.zeros((10, 2), np.float32)
    kernel[8:10] = -np.eye(2, dtype=np.float32)  # push the fingertip toward the target
    policy = tmp_path / "p.npz"
    policy.write_bytes(
        npz_bytes(NumpyPolicy((kernel,), (np.zeros(2, np.float32),), None, False, meta))
    )
    summary, log = tmp_path / "s.json", tmp_path / "l.mcap"
    done = subprocess.run(
        [
            sys.executable,
            "-m",
            "jaxenvs",
            "deploy",
            str(policy),
            "--env",
            "Reacher-v0",
            "--robot",
            "sim",
            "--seconds",
            "1",
            "--summary",
            str(summary),
            "--log",
            str(log),
        ],
        capture_output=True,
        text=True,
        env=_env(),
        timeout=60,
    )
    assert done.returncode == 0, done.stderr
    s = json.loads(summary.read_text())
    assert s["steps"] == 50 and s["error"] is None and -50 * 0.6 < s["return"] < 0
    commands = read_log(log)["/deploy/command"]
    target = read_log(log)["/robot/state"][0]["mocap_pos"][0][:2]
    assert all(c["task"] == pytest.approx(target) for c in commands)


@pytest.mark.full
def test_robot_killed_mid_run(tmp_path):
    robot = _jaxenvs("robot", "CartPole-v0", "--listen", "tcp://127.0.0.1:0", "--once")
    assert robot.stdout is not None
    address = robot.stdout.readline().strip().removeprefix("listening on ")
    log = tmp_path / "l.mcap"
    deploy = _jaxenvs(
        "deploy",
        str(pd_policy(tmp_path / "pd.npz")),
        "--env",
        "CartPole-v0",
        "--robot",
        address,
        "--seconds",
        "30",
        "--log",
        str(log),
    )
    try:
        _until_running(deploy)
        time.sleep(0.3)
        robot.send_signal(signal.SIGKILL)
        _failed_fast(deploy, time.time(), "the robot closed the link", log)
    finally:
        robot.kill()
        deploy.kill()
        robot.communicate()


def _garbage_robot(spec: dict, server: socket.socket, garbage: bytes) -> None:
    """Say hello, send five good sensor frames, then the frame ``garbage``."""
    conn, _ = server.accept()
    with conn:
        conn.sendall(wire.encode({"type": "hello", "version": wire.VERSION, **spec}))
        for k in range(5):
            readings = {s["name"]: [0.0] * s["size"] for s in spec["sensors"]}
            conn.sendall(wire.encode(wire.sensors(k, k * 0.02, -1, readings)))
            time.sleep(0.02)
        conn.sendall(struct_frame(garbage))
        try:
            while conn.recv(1 << 16):
                pass
        except OSError:
            pass


def struct_frame(body: bytes) -> bytes:
    return len(body).to_bytes(4, "big") + body


GARBAGE = {
    "not_json": b"\x00garbage\xff",
    "long_integer": b'{"type":"sensors","seq":5,"stamp":0.1,"acked":-1,"readings":{"slider_pos":['
    + b"1" * 400
    + b'],"hinge_pos":[0],"slider_vel":[0],"hinge_vel":[0]}}',
    "deep_nesting": b"[" * 200_000 + b"]" * 200_000,
    "seq_of_5000_digits": b'{"type":"sensors","seq":' + b"7" * 5000 + b"}",
}


@pytest.mark.full
@pytest.mark.parametrize("garbage", sorted(GARBAGE))
def test_robot_sending_garbage(tmp_path, garbage):
    """Frames that are not JSON, or that used to crash the process (a traceback, no
    summary, a hold saying "done"): a hold naming the malformed message, exit 1."""
    import jaxenvs
    from jaxenvs.robots.interface import spec_of

    spec = spec_of(jaxenvs.make("CartPole-v0", physics="c"), "CartPole-v0").to_json()
    server = socket.create_server(("127.0.0.1", 0))
    args = (spec, server, GARBAGE[garbage])
    thread = threading.Thread(target=_garbage_robot, args=args, daemon=True)
    thread.start()
    log = tmp_path / "l.mcap"
    deploy = _jaxenvs(
        "deploy",
        str(pd_policy(tmp_path / "pd.npz")),
        "--env",
        "CartPole-v0",
        "--robot",
        f"tcp://127.0.0.1:{server.getsockname()[1]}",
        "--seconds",
        "30",
        "--log",
        str(log),
        "--summary",
        str(tmp_path / "s.json"),
    )
    try:
        _until_running(deploy)
        _failed_fast(deploy, time.time(), "malformed message from the robot", log)
    finally:
        deploy.kill()
        server.close()
    summary = json.loads((tmp_path / "s.json").read_text())
    assert summary["error"].startswith("malformed message from the robot")


@pytest.mark.full
@pytest.mark.parametrize(
    ("gains", "flags", "cause"),
    [
        (np.array([0, 0, np.nan, 0], np.float32), (), "the policy's output is not finite"),
        (PD_GAINS, ("--max-late-ms", "0.001"), "overrun"),
    ],
    ids=["nan_policy", "overrun"],
)
def test_policy_failures_hold_and_stop(tmp_path, gains, flags, cause):
    log = tmp_path / "l.mcap"
    deploy = _jaxenvs(
        "deploy",
        str(pd_policy(tmp_path / "p.npz", gains)),
        "--env",
        "CartPole-v0",
        "--robot",
        "sim",
        "--seconds",
        "30",
        "--log",
        str(log),
        *flags,
    )
    try:
        _until_running(deploy)
        _failed_fast(deploy, time.time(), cause, log, ran=False)
    finally:
        deploy.kill()


@pytest.mark.full
def test_deploy_refuses_a_policy_of_another_task(tmp_path):
    done = subprocess.run(
        [
            sys.executable,
            "-m",
            "jaxenvs",
            "deploy",
            str(pd_policy(tmp_path / "pd.npz")),
            "--env",
            "Reacher-v0",
            "--robot",
            "sim",
            "--seconds",
            "1",
        ],
        capture_output=True,
        text=True,
        env=_env(),
        timeout=60,
    )
    assert done.returncode == 2
    assert done.stderr.strip() == (
        f"jaxenvs deploy: error: {tmp_path / 'pd.npz'} is a policy of CartPole-v0, not Reacher-v0"
    )


def test_command_script_holds_each_value_until_the_next(tmp_path):
    from jaxenvs.deploy.commands import CommandInput

    script = tmp_path / "cmd.txt"
    script.write_text("# t vx vy\n0 0.1 0.0\n2.5 0.2 -0.1  # faster\n\n")
    commands = CommandInput(str(script))
    assert commands.at(1.0).tolist() == pytest.approx([0.1, 0.0])
    assert commands.at(2.5).tolist() == pytest.approx([0.2, -0.1])
    commands.expect((2,), "Reacher-v0")
    with pytest.raises(ValueError, match="the command at 0 s has 2 values, Reacher-v0 takes 3"):
        commands.expect((3,), "Reacher-v0")
    with pytest.raises(ValueError, match="CartPole-v0 takes no task input"):
        commands.expect((), "CartPole-v0")
    script.write_text("1 0.5\n")
    with pytest.raises(ValueError, match="cmd.txt:1: the command script must start at 0 s, not 1"):
        CommandInput(str(script))
    script.write_text("1 fast\n")
    with pytest.raises(ValueError, match=r"cmd.txt:1: expected 'T v1 v2 \.\.\.' numbers"):
        CommandInput(str(script))


def test_log_of_a_killed_writer_is_readable_up_to_its_last_chunk(tmp_path):
    """A writer that never finished (its process killed) leaves every whole chunk readable."""
    from jaxenvs.deploy.log import CHUNK, LogWriter

    path = tmp_path / "l.mcap"
    writer = LogWriter(path)
    writer.write("/robot/hello", {"env_id": "CartPole-v0"})
    n = 4 * CHUNK // 60
    for k in range(n):
        writer.write("/deploy/command", {"step": k, "command": [0.5]})
    partial = tmp_path / "partial.mcap"
    partial.write_bytes(path.read_bytes())  # the file as a killed process would leave it
    writer.close()
    steps = [m["step"] for m in read_log(partial)["/deploy/command"]]
    assert len(steps) > n // 2 and steps == list(range(len(steps)))
    finished = read_log(path)
    assert [m["step"] for m in finished["/deploy/command"]] == list(range(n))
    assert finished["/robot/hello"] == [{"env_id": "CartPole-v0"}]


@pytest.mark.parametrize(
    ("env_id", "robot", "terrain", "message"),
    [
        ("CartPole-v0", "sim", "3", "--terrain: CartPole-v0 has no terrain"),
        ("HexapodJoystickRough-v0", "sim", "12", "--terrain: the level must be 0..9, got '12'"),
        (
            "HexapodJoystickRough-v0",
            "tcp://127.0.0.1:9",
            "3",
            "--latency-ms, --jitter-ms, --noise and --terrain set up --robot sim",
        ),
    ],
)
def test_deploy_refuses_a_terrain_it_cannot_set_up(tmp_path, env_id, robot, terrain, message):
    """``--terrain`` starts the simulated robot on a tile; it is refused, before any robot
    starts, for a task without a terrain, a level it does not have, or a real robot."""
    done = subprocess.run(
        [sys.executable, "-m", "jaxenvs", "deploy", str(pd_policy(tmp_path / "pd.npz"))]
        + ["--env", env_id, "--robot", robot, "--seconds", "1", "--terrain", terrain],
        capture_output=True,
        text=True,
        env=_env(),
        timeout=60,
    )
    assert done.returncode == 2, done.stderr
    assert done.stderr.strip() == f"jaxenvs deploy: error: {message}"
