"""``jaxenvs deploy`` against robots that misbehave and inputs that are wrong: each is a
hold naming the fault (exit 1, summary and log written) or a one-line refusal (exit 2)
before the robot moves. The robot is a thread speaking the wire (:class:`FakeRobot`), the
deploy runs in this process (``cli.main``)."""

from __future__ import annotations

import contextlib
import errno
import json
import select
import socket
import threading
import time
from pathlib import Path

import numpy as np
import pytest
from pd_policy import pd_policy

import jaxenvs
from jaxenvs import cli
from jaxenvs.deploy import log as log_mod
from jaxenvs.deploy import simrobot, wire
from jaxenvs.deploy.export import npz_bytes
from jaxenvs.deploy.log import read_log
from jaxenvs.deploy.runtime import FORMAT, FORMAT_VERSION, NumpyPolicy
from jaxenvs.robots.interface import spec_of

KEY = b"0123456789abcdef0123456789abcdef"


@pytest.fixture(scope="module")
def spec() -> dict:
    return spec_of(jaxenvs.make("CartPole-v0", physics="c"), "CartPole-v0").to_json()


@pytest.fixture()
def policy(tmp_path) -> Path:
    """CartPole-v0's PD controller as an exported ``.npz``."""
    return pd_policy(tmp_path / "pd.npz")


def _raw(body: bytes) -> bytes:
    return len(body).to_bytes(4, "big") + body


class FakeRobot:
    """A robot in a thread: (a challenge, with ``key``), a hello of ``spec`` (or the raw
    JSON ``hello``), then a zero sensor frame every 20 ms acknowledging the last command
    (or ``acked(k)``), and after ``after`` frames the raw frames of ``bad``. It keeps what
    it receives in ``received``."""

    def __init__(self, spec, hello=None, bad=(), after=5, acked=None, key=None) -> None:
        self.spec, self.hello = spec, hello
        self.bad, self.after, self.acked, self.key = list(bad), after, acked, key
        self.received: list[dict] = []
        self.server = socket.create_server(("127.0.0.1", 0))
        self.address = f"tcp://127.0.0.1:{self.server.getsockname()[1]}"
        self.thread = threading.Thread(target=self._serve, daemon=True)
        self.thread.start()

    def _serve(self) -> None:
        conn, _ = self.server.accept()
        with conn:
            conn.settimeout(5)
            try:
                self._run(conn)
            except OSError:
                pass

    def _run(self, conn: socket.socket) -> None:
        reader, mac = wire.FrameReader(), None
        if self.key is not None:
            mac = simrobot.answer_challenge(conn, self.key, reader)
            if isinstance(mac, dict):
                conn.sendall(wire.encode({"type": "bye", "reason": mac["refused"]}))
                return
        hello = {"type": "hello", "version": 1, **self.spec}
        if self.hello is not None:
            conn.sendall(_raw(self.hello))
        else:
            conn.sendall(wire.encode(hello if mac is None else {**hello, "mac": mac}))
        last = -1
        for k in range(500):
            readings = {s["name"]: [0.0] * s["size"] for s in self.spec["sensors"]}
            acked = last if self.acked is None else self.acked(k)
            conn.sendall(wire.encode(wire.sensors(k, k * 0.02, acked, readings)))
            if k == self.after:
                for frame in self.bad:
                    conn.sendall(frame)
            time.sleep(0.02)
            if not select.select([conn], [], [], 0)[0]:
                continue
            data = conn.recv(1 << 16)
            if not data:
                return
            self.received += reader.feed(data)
            last = max([m["seq"] for m in self.received if m["type"] == "command"] + [last])
            if any(m["type"] == "bye" for m in self.received):
                return

    def of(self, kind: str) -> list[dict]:
        return [m for m in self.received if m["type"] == kind]

    def close(self) -> None:
        self.thread.join(5)
        self.server.close()


def _deploy(capsys, policy, robot, tmp_path, *extra, seconds="3"):
    """``jaxenvs deploy`` in this process: (status, stderr, summary or None, log path)."""
    summary, log = tmp_path / "s.json", tmp_path / "l.mcap"
    argv = ["deploy", str(policy), "--env", "CartPole-v0", "--robot", robot.address]
    argv += ["--seconds", seconds, "--summary", str(summary), "--log", str(log), *extra]
    try:
        code = cli.main(argv)
    finally:
        robot.close()
    err = capsys.readouterr().err.strip()
    return code, err, json.loads(summary.read_text()) if summary.exists() else None, log


def _held_on(robot: FakeRobot, code: int, err: str, s: dict, log: Path, fault: str) -> None:
    """Exit 1 with one line naming ``fault``; the robot was told to hold for it, after
    every command; the summary and the log say so."""
    assert code == 1, err
    assert len(err.splitlines()) == 1 and err.startswith("jaxenvs deploy: error:"), err
    assert fault in err, err
    holds = robot.of("hold")
    assert holds and fault in holds[0]["reason"], robot.received
    assert all(holds[0]["seq"] > c["seq"] for c in robot.of("command"))
    assert s is not None and fault in s["error"]
    messages = read_log(log)
    assert fault in messages["/deploy/event"][0]["reason"] and messages["/deploy/summary"]


# --------------------------------------------------------------------- a wire nothing crashes
KILLERS = {
    "long_integer": b'{"type":"sensors","seq":9,"stamp":0.2,"acked":-1,"readings":'
    b'{"slider_pos":[' + b"1" * 400 + b'],"hinge_pos":[0],"slider_vel":[0],"hinge_vel":[0]}}',
    "deep_nesting": b"[" * 200_000 + b"]" * 200_000,
    "seq_of_5000_digits": b'{"type":"sensors","seq":' + b"7" * 5000 + b"}",
}


@pytest.mark.parametrize("name", sorted(KILLERS))
def test_a_frame_that_crashed_the_loop_is_a_hold_naming_it(capsys, policy, spec, tmp_path, name):
    """Frames that raised OverflowError, RecursionError or Python's integer-string limit
    inside the loop: a hold naming the malformed message, exit 1, summary and log."""
    robot = FakeRobot(spec, bad=[_raw(KILLERS[name])])
    code, err, s, log = _deploy(capsys, policy, robot, tmp_path)
    _held_on(robot, code, err, s, log, "malformed message from the robot")
    assert s["bad_messages"] == {"non_finite" if name == "long_integer" else "malformed": 1}


def test_an_ack_of_a_command_never_sent_is_a_fault(capsys, policy, spec, tmp_path):
    """A frame acknowledging a command the loop has not sent (it used to make a negative
    round trip) stops the run."""
    robot = FakeRobot(spec, acked=lambda k: k + 50)
    code, err, s, log = _deploy(capsys, policy, robot, tmp_path)
    _held_on(robot, code, err, s, log, "beyond the last command sent")
    assert s["round_trip_ms_p50"] is None


def test_hold_carries_a_seq_above_every_command(capsys, policy, spec, tmp_path):
    robot = FakeRobot(spec)
    code, err, s, _ = _deploy(capsys, policy, robot, tmp_path, seconds="0.3")
    assert code == 0, err
    commands, (hold,) = robot.of("command"), robot.of("hold")
    assert len(commands) == 15 and hold["seq"] == commands[-1]["seq"] + 1 == 15
    assert hold["reason"] == "done" and s["round_trip_ms_p50"] > 0


def test_a_robot_flooding_the_link_with_stale_frames_is_a_hold(capsys, policy, spec, tmp_path):
    """A robot that, after a few fresh frames, sends its last one again without pause
    (each counted stale and dropped): the loop used to read on for as long as bytes came,
    never reaching its sensor timeout. Now a poll reads a bounded amount, the timeout
    fires, the robot is told to hold and the run ends. (The flood stops by itself after
    30 s, so that a loop that reads on fails this test instead of hanging it.)"""
    server = socket.create_server(("127.0.0.1", 0))
    received: list[dict] = []
    flooding: list[float] = []

    def serve() -> None:
        conn, _ = server.accept()
        with conn, contextlib.suppress(OSError):  # until the loop closes the link
            conn.sendall(wire.encode({"type": "hello", "version": 1, **spec}))
            readings = {s["name"]: [0.0] * s["size"] for s in spec["sensors"]}

            def read() -> None:
                reader = wire.FrameReader()
                with contextlib.suppress(OSError):
                    while data := conn.recv(1 << 16):
                        received.extend(reader.feed(data))

            threading.Thread(target=read, daemon=True).start()
            for k in range(5):
                frame = wire.encode(wire.sensors(k, k * 0.02, -1, readings))
                conn.sendall(frame)
                time.sleep(0.02)
            flooding.append(time.monotonic())
            while time.monotonic() < flooding[0] + 30:
                conn.sendall(frame * 2000)

    threading.Thread(target=serve, daemon=True).start()
    summary = tmp_path / "s.json"
    argv = ["deploy", str(policy), "--env", "CartPole-v0", "--robot"]
    argv += [f"tcp://127.0.0.1:{server.getsockname()[1]}", "--seconds", "20"]
    try:
        code = cli.main([*argv, "--summary", str(summary)])
    finally:
        server.close()
    end = time.monotonic()
    err = capsys.readouterr().err
    # the sensor timeout, or on a loaded machine the step's deadline: a hold either way
    assert code == 1 and ("no sensor message" in err or "overrun" in err), err
    assert flooding, f"the loop stopped before the flood began: {err}"
    assert end - flooding[0] < 10, f"the loop read the flood for {end - flooding[0]:.1f} s"
    assert any(m["type"] == "hold" for m in received)
    assert json.loads(summary.read_text())["bad_messages"]["stale"] > 0


# ---------------------------------------------------------------- what the robot declares
@pytest.mark.parametrize(
    ("hello", "says"),
    [
        ({"actuators": [{"name": "force", "low": -100.0, "high": 100.0}]}, "-100..100"),
        ({"actuators": [{"name": "force", "low": float("nan"), "high": 1.0}]}, "nan..1"),
        ({"control_dt": float("nan")}, "bad robot description"),
        (
            {"sensors": [{"name": "slider_pos", "size": 1e400, "unit": "m", "kind": "x"}]},
            "bad robot description",
        ),
    ],
    ids=["limits", "nan_limit", "nan_control_dt", "infinite_size"],
)
def test_a_robot_declaring_another_robot_is_refused(capsys, policy, spec, tmp_path, hello, says):
    """Actuator limits the task was not trained with (100x the force), a NaN period or an
    infinite sensor size: one line, exit 2, no command sent."""
    raw = json.dumps({"type": "hello", "version": 1, **spec, **hello}).encode()
    robot = FakeRobot(spec, hello=raw)
    code, err, s, _ = _deploy(capsys, policy, robot, tmp_path)
    assert code == 2 and len(err.splitlines()) == 1, err
    assert err.startswith("jaxenvs deploy: error:") and says in err, err
    assert not robot.of("command") and s is None


def test_the_wrong_key_is_one_line(capsys, policy, spec, tmp_path):
    key = tmp_path / "robot.key"
    key.write_bytes(b"not-the-robots-key-but-long-enough")
    key.chmod(0o600)
    robot = FakeRobot(spec, key=KEY)
    code, err, _, _ = _deploy(capsys, policy, robot, tmp_path, "--key-file", str(key))
    assert code == 2 and err.endswith("refused the key (not its key?)"), err
    assert not robot.received


# ------------------------------------------------------------------------- a full disk
def _disk_of(monkeypatch, capacity: int) -> None:
    """The log's disk holds ``capacity`` bytes, then every write fails with ENOSPC."""
    used = {"n": 0}
    real = log_mod._write

    def write(fd, data):
        room = capacity - used["n"]
        if room <= 0:
            raise OSError(errno.ENOSPC, "No space left on device")
        n = real(fd, data[:room])
        used["n"] += n
        return n

    monkeypatch.setattr(log_mod, "_write", write)


def test_a_full_disk_holds_the_robot_and_leaves_a_readable_log(
    capsys, policy, spec, tmp_path, monkeypatch
):
    """The disk fills mid-run: a hold naming it, exit 1, the summary written elsewhere,
    and the log readable (and renderable) up to its last whole record."""
    _disk_of(monkeypatch, 3 * log_mod.CHUNK)
    robot = FakeRobot(spec)
    code, err, s, log = _deploy(capsys, policy, robot, tmp_path, seconds="6")
    full = "No space left on device"
    assert code == 1 and full in err and f"cannot write the log {log}" in err, err
    assert full in robot.of("hold")[0]["reason"] and full in s["error"]
    assert 20 < s["steps"] < 300
    messages = read_log(log)
    steps = [c["step"] for c in messages["/deploy/command"]]
    assert messages["/robot/hello"] and steps == list(range(len(steps))) and len(steps) > 10
    assert log.stat().st_size <= 3 * log_mod.CHUNK
    video = tmp_path / "v.mp4"
    argv = ["render", "--log", str(log), "--out", str(video), "--width", "64", "--height", "48"]
    assert cli.main(argv) == 0
    assert f"{len(messages['/robot/sensors'])} frames" in capsys.readouterr().out


def test_log_writer_on_a_full_disk(tmp_path, monkeypatch):
    """A write or the finish that fails raises LogError once; the file keeps its whole
    records and reads back; later writes are dropped."""
    path = tmp_path / "l.mcap"
    _disk_of(monkeypatch, 2 * log_mod.CHUNK + 100)
    writer = log_mod.LogWriter(path)
    writer.write("/robot/hello", {"env_id": "CartPole-v0"})
    with pytest.raises(log_mod.LogError, match="No space left on device"):
        for k in range(10_000):
            writer.write("/deploy/command", {"step": k, "command": [0.5]})
    writer.write("/deploy/command", {"step": -1})  # dropped
    writer.close()
    steps = [m["step"] for m in read_log(path)["/deploy/command"]]
    assert len(steps) > 100 and steps == list(range(len(steps)))
    small = tmp_path / "small.mcap"
    monkeypatch.undo()
    writer = log_mod.LogWriter(small)
    for k in range(20):
        writer.write("/deploy/command", {"step": k})
    _disk_of(monkeypatch, 0)  # the finish fails
    with pytest.raises(log_mod.LogError, match="No space left"):
        writer.close()
    writer.close()


@pytest.mark.parametrize("cut", [0.1, 0.37, 0.5, 0.73, 0.99])
def test_read_log_of_a_file_cut_anywhere(tmp_path, cut):
    path = tmp_path / "l.mcap"
    writer = log_mod.LogWriter(path)
    writer.write("/robot/hello", {"env_id": "CartPole-v0"})
    for k in range(3000):
        writer.write("/deploy/command", {"step": k})
    writer.close()
    data = path.read_bytes()
    path.write_bytes(data[: int(len(data) * cut)])
    steps = [m["step"] for m in read_log(path)["/deploy/command"]]
    assert steps == list(range(len(steps)))


# --------------------------------------------------------------------- the command script
@pytest.mark.parametrize(
    ("script", "says"),
    [
        ("0 0.1 0.1\n1 nan 0.1\n", "cmd.txt:2: every number must be finite"),
        ("0 0.1 0.1\n1 inf 0.1\n", "cmd.txt:2: every number must be finite"),
        ("-1 0.1 0.1\n", "cmd.txt:1: the command script must start at 0 s, not -1"),
        ("0 0.1 0.1\n2 0 0\n1 0 0\n", "cmd.txt:3: times must increase"),
        ("0 0.1 0.1\n1 0.1\n", "cmd.txt:2: 1 values, the first line has 2"),
        ("0 1e39 0\n", "cmd.txt:1: a value does not fit a 32-bit float"),
    ],
)
def test_command_script_is_checked_whole_when_read(tmp_path, script, says):
    from jaxenvs.deploy.commands import CommandInput

    path = tmp_path / "cmd.txt"
    path.write_text(script)
    with pytest.raises(ValueError, match=says):
        CommandInput(str(path))


def test_command_script_outside_the_tasks_range_is_refused(tmp_path):
    from jaxenvs.deploy.commands import CommandInput, input_range

    reacher = input_range(jaxenvs.make("Reacher-v0", physics="c"))
    joystick = input_range(jaxenvs.make("HexapodJoystick-v0", physics="c"))
    path = tmp_path / "cmd.txt"
    path.write_text("0 0.1 0.1\n2 0.5 0.5\n")
    with pytest.raises(ValueError, match=r"at 2 s is outside Reacher-v0's range: .* radius 0\.2"):
        CommandInput(str(path)).expect((2,), "Reacher-v0", reacher)
    path.write_text("0 0.3 0 0\n5 0 0 3.0\n")
    with pytest.raises(ValueError, match=r"at 5 s .*: value 3 \(3\) is outside \[-0\.8, 0\.8\]"):
        CommandInput(str(path)).expect((3,), "HexapodJoystick-v0", joystick)
    path.write_text("0 0.1 -0.12\n1 0 0.2\n")
    CommandInput(str(path)).expect((2,), "Reacher-v0", reacher)  # inside: accepted
    typed = CommandInput(str(path))
    typed.expect((2,), "Reacher-v0", reacher)
    assert typed._typed("0.3 0.3").startswith("outside the task's range")
    assert typed._typed("nan 0") == "expected finite numbers"
    assert typed._typed("0.1 0.05").tolist() == pytest.approx([0.1, 0.05])


# ------------------------------------------------------------------------- policy files
def test_policy_is_read_by_its_content(tmp_path, policy):
    from jaxenvs.deploy.loop import HostPolicy

    misnamed = tmp_path / "pd.onnx"  # an npz under an ONNX name: read as what it is
    misnamed.write_bytes(policy.read_bytes())
    assert HostPolicy(misnamed).format == "npz"
    bad = tmp_path / "bad.onnx"
    for data, says in [
        (b"\x08\x07\x12\x05junk!" * 3, "not a readable ONNX model or .npz"),
        (policy.read_bytes()[:100], "not a readable npz"),
        (b"", "an empty file"),
    ]:
        bad.write_bytes(data)
        with pytest.raises(ValueError, match=says) as err:
            HostPolicy(bad)
        assert "\n" not in str(err.value)


def test_a_truncated_onnx_policy_is_one_line(tmp_path, capsys):
    from jaxenvs.deploy.export import onnx_model

    source = tmp_path / "pd.npz"
    kernel = np.zeros((4, 2), np.float32)
    meta = {"format": FORMAT, "format_version": FORMAT_VERSION, "env_id": "CartPole-v0"}
    meta |= {"observation_size": "4", "action_size": "2", "discrete": "1"}
    meta |= {"control_dt": "0.02", "activation": "tanh", "jaxenvs_version": "0"}
    source.write_bytes(
        npz_bytes(NumpyPolicy((kernel,), (np.zeros(2, np.float32),), None, True, meta))
    )
    data = onnx_model(NumpyPolicy.load(source)).SerializeToString()
    cut = tmp_path / "cut.onnx"
    cut.write_bytes(data[: len(data) // 2])
    argv = ["deploy", str(cut), "--env", "CartPole-v0", "--robot", "tcp://127.0.0.1:9"]
    assert cli.main([*argv, "--seconds", "1"]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "not a readable ONNX model or .npz" in err, err


def test_export_refuses_an_out_named_as_the_other_format_and_names_the_seed_range(tmp_path, capsys):
    """``--format npz --out m.onnx`` (it wrote an npz under an ONNX name) and ``--seed -1``
    (it named 0..2147483647): one line each, before anything is restored."""
    import yaml

    from jaxenvs.run import runner

    run = tmp_path / "run"
    run.mkdir()
    resolved = runner.resolve_config("CartPole-v0", "ppo")
    (run / runner.CONFIG_FILE).write_text(yaml.safe_dump(resolved.to_dict()))
    out = tmp_path / "m.onnx"
    assert cli.main(["export", str(run), "--format", "npz", "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip()
    assert err == f"jaxenvs export: error: --out {out} is named as onnx, but --format is npz"
    assert not out.exists()
    assert cli.main(["export", str(run), "--format", "npz", "--seed", "-1"]) == 2
    err = capsys.readouterr().err.strip()
    assert err == f"jaxenvs export: error: --seed must be between 0 and 0 for {run}"


@pytest.mark.parametrize("typed", ["", "oops\n", "0.1 0.2\n"])
def test_standard_input_ending_before_a_task_input_is_one_line(monkeypatch, typed):
    """``--command -`` with standard input at its end before any valid input (a closed
    pipe, ``</dev/null``): the loop used to wait for it for ever; now one line says so.
    Input typed before the end still starts the run."""
    import io
    import types

    from jaxenvs.deploy import loop
    from jaxenvs.deploy.commands import CommandInput

    monkeypatch.setattr("sys.stdin", io.StringIO(typed))
    st = types.SimpleNamespace(
        commands=CommandInput("-"), host=types.SimpleNamespace(needs_input=True), truth=None
    )
    link = types.SimpleNamespace(latest=lambda: "a frame", privileged=False)
    opts = types.SimpleNamespace(first_frame_s=1.0)
    errors: list[BaseException] = []

    def wait() -> None:
        try:
            loop._first_frame(link, st, None, opts, None)
        except loop.DeployError as err:
            errors.append(err)

    run = threading.Thread(target=wait, daemon=True)
    run.start()
    run.join(10)
    assert not run.is_alive(), "the loop still waits for input that cannot come"
    assert st.commands.exhausted
    if typed.startswith("0.1"):
        assert not errors and st.commands.at(0.0).tolist() == pytest.approx([0.1, 0.2])
    else:
        assert [str(e) for e in errors] == ["standard input ended before the first task input"]
