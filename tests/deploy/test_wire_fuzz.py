"""Random and mutated frames (hypothesis) thrown at both ends of the robot link: the
simulated robot counts every bad one, applies only valid commands, holds otherwise and
keeps serving; the loop's side raises nothing but ``LinkError``, and the loop holds the
robot. Some 700 examples in the default tier (about 10 s in all on two cores), five to ten
times as many under ``-m full`` (one to two minutes)."""

from __future__ import annotations

import itertools
import json
import socket
import threading
import time
import types

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from jaxenvs.deploy import loop, simrobot, wire
from jaxenvs.deploy.link import TcpRobot
from jaxenvs.robots.interface import LinkError

SIZES = {"slider_pos": 1, "hinge_pos": 1, "slider_vel": 1, "hinge_vel": 1}
PROBE = 10**17  # a command seq above every one the strategies make (at most 10**6)


def _raw(body: bytes) -> bytes:
    return len(body).to_bytes(4, "big") + body


def _settings(examples: int):
    return settings(
        max_examples=examples,
        deadline=None,
        database=None,
        suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large],
    )


# --------------------------------------------------------------------------- the frames
NUMBERS = st.one_of(
    st.integers(-(10**6), 10**6).map(str),
    st.floats(allow_nan=False, allow_infinity=False).map(repr),
    st.sampled_from(["NaN", "Infinity", "-Infinity", "1e400", "-1e999", "1.5", "-1", "true"]),
    st.integers(19, 6000).map(lambda n: "9" * n),  # beyond a float, beyond int-string limits
)
LEAVES = st.one_of(NUMBERS, st.just("null"), st.text(max_size=12).map(json.dumps))
VALUES = st.recursive(
    LEAVES,
    lambda inner: st.one_of(
        st.lists(inner, max_size=4).map(lambda xs: "[" + ",".join(xs) + "]"),
        st.dictionaries(st.text(max_size=8), inner, max_size=3).map(
            lambda d: "{" + ",".join(f"{json.dumps(k)}:{v}" for k, v in d.items()) + "}"
        ),
    ),
    max_leaves=12,
)
TYPES = st.sampled_from(["command", "sensors", "state", "hold", "bye", "hello", "auth", "x"])
FIELDS = ("seq", "action", "stamp", "acked", "readings", "qpos", "qvel", "mocap_pos", "counts")


@st.composite
def messages(draw) -> bytes:
    """A JSON object with a type and some of the messages' fields, of any values."""
    kind = draw(st.one_of(TYPES.map(json.dumps), VALUES))
    fields = draw(st.dictionaries(st.sampled_from(FIELDS), VALUES, max_size=5))
    readings = draw(st.booleans())
    if readings:  # a sensors frame's readings, each sensor's values of any kind
        values = draw(st.lists(st.one_of(NUMBERS, VALUES), min_size=4, max_size=4))
        fields["readings"] = (
            "{" + ",".join(f'"{n}":[{v}]' for n, v in zip(SIZES, values, strict=True)) + "}"
        )
    body = ",".join([f'"type":{kind}'] + [f'"{k}":{v}' for k, v in fields.items()])
    return ("{" + body + "}").encode()


def _valid(seq: int) -> list[bytes]:
    readings = {n: np.array([0.1]) for n in SIZES}
    return [
        json.dumps(wire.command(seq, np.array([0.5]))).encode(),
        json.dumps(wire.sensors(seq, 0.02 * seq, 0, readings)).encode(),
    ]


@st.composite
def mutated(draw) -> bytes:
    """A valid command or sensors frame with bytes changed, inserted or deleted."""
    body = bytearray(draw(st.sampled_from(_valid(draw(st.integers(0, 1000))))))
    for _ in range(draw(st.integers(1, 4))):
        at = draw(st.integers(0, len(body)))
        edit = draw(st.sampled_from(["set", "insert", "delete"]))
        byte = draw(st.integers(0, 255))
        if edit == "insert":
            body.insert(at, byte)
        elif at < len(body):
            body[at : at + 1] = b"" if edit == "delete" else bytes([byte])
    return bytes(body) or b" "


DEEP = st.integers(1, 300_000).map(lambda n: b"[" * n + b"]" * n)
BODIES = st.one_of(messages(), mutated(), DEEP, st.binary(min_size=1, max_size=64))


# ------------------------------------------------------------------------ the robot's end
@pytest.fixture(scope="module")
def world():
    return simrobot.build_world("CartPole-v0", seed=0)


def _robot_end(world, examples: int) -> None:
    hold_ctrl = simrobot._Episode(world, world.starts[0], None).ctrl_of(np.zeros(1))

    @_settings(examples)
    @given(bodies=st.lists(BODIES, min_size=1, max_size=6))
    def check(bodies):
        ep = simrobot._Episode(world, world.starts[0], None)
        ep.hold()
        handled = 0
        for body in bodies:
            for msg in ep.reader.feed(_raw(body)):
                acked = ep.acked
                ep.handle(msg)
                handled += ep.acked != acked or msg["type"] in ("hold", "bye")
        assert sum(ep.counts.values()) + handled == len(bodies)  # every frame accounted
        ctrl = np.asarray(ep.data.ctrl)
        assert np.all(np.isfinite(ctrl))
        assert np.all((world.ctrl_low <= ctrl) & (ctrl <= world.ctrl_high))
        if ep.acked == -1:  # no valid command: still holding
            assert ep.held and np.array_equal(ctrl, hold_ctrl)

    check()


@pytest.mark.parametrize(
    "examples", [300, pytest.param(1500, marks=pytest.mark.full)], ids=["quick", "long"]
)
def test_robot_end_counts_every_bad_frame_and_holds(world, examples):
    _robot_end(world, examples)


def _serving(world, examples: int) -> None:
    """Each example: one real-time episode on a socket pair, fuzzed frames, then a valid
    command that must be applied and acknowledged (the robot still serves)."""

    @_settings(examples)
    @given(bodies=st.lists(BODIES.filter(lambda b: b"bye" not in b), min_size=1, max_size=5))
    def check(bodies):
        ours, theirs = socket.socketpair()
        result: dict = {}
        opts = simrobot.LinkOptions(seconds=5)

        def robot():
            with ours:
                result["ep"] = simrobot.run_episode(world, ours, world.starts[0], opts)

        thread = threading.Thread(target=robot)
        thread.start()
        reader = wire.FrameReader()
        stream = b"".join(_raw(b) for b in bodies) + wire.encode(wire.command(PROBE, np.ones(1)))
        sender = threading.Thread(target=theirs.sendall, args=(stream,))
        sender.start()
        acked, end = -1, time.monotonic() + 5
        while acked != PROBE and time.monotonic() < end:
            for msg in reader.feed(theirs.recv(1 << 16)):
                acked = msg.get("acked", acked) if msg["type"] == "sensors" else acked
        sender.join(5)
        theirs.sendall(wire.encode({"type": "bye", "reason": "done"}))
        thread.join(10)
        theirs.close()
        assert acked == PROBE and result["ep"].closed == "bye"

    check()


@pytest.mark.parametrize(
    "examples", [12, pytest.param(150, marks=pytest.mark.full)], ids=["quick", "long"]
)
def test_robot_keeps_serving_after_fuzzed_frames(world, examples):
    _serving(world, examples)


# ------------------------------------------------------------------------- the loop's end
def _link_end(examples: int) -> None:
    @_settings(examples)
    @given(bodies=st.lists(BODIES, min_size=1, max_size=6))
    def check(bodies):
        robot = TcpRobot("tcp://127.0.0.1:1")
        robot._sizes, robot._sent = dict(SIZES), 5
        robot._dims = (2, 2, 0)
        try:
            for body in bodies:
                for msg in robot._feed(_raw(body)):
                    robot._handle(msg, time.monotonic())
        except LinkError as err:
            assert "\n" not in str(err) and str(err).startswith("malformed message")
        frame = robot._latest
        if frame is not None:
            assert all(np.all(np.isfinite(v)) for v in frame.readings.values())
            assert -1 <= frame.acked <= 5

    check()


@pytest.mark.parametrize(
    "examples", [400, pytest.param(3000, marks=pytest.mark.full)], ids=["quick", "long"]
)
def test_loop_end_raises_only_link_errors(examples):
    _link_end(examples)


class _Host:
    """The loop's view of CartPole's task, in numpy (no JAX)."""

    env = types.SimpleNamespace(control_dt=0.01)
    zero_history = np.zeros((1, 1), np.float32)
    zero_command = np.zeros(1)
    zero_action = np.zeros(1, np.float32)
    default_task_state = None
    needs_input = False

    def observe(self, readings, task):
        return np.concatenate([readings[n] for n in SIZES]).astype(np.float32)

    def with_action_history(self, task, actions):
        return task

    def with_clock(self, task, steps):
        return task

    def prior_action(self, task, action):
        return action

    def actuator_command(self, action, previous):
        return np.asarray(action, np.float64)

    @staticmethod
    def pushed(history, action):
        return history


class _Policy:
    def act(self, obs):
        return np.clip(obs[:1], -1, 1), True


def _fuzzing_robot(server: socket.socket, bodies: list[bytes], got: list) -> None:
    """Hello, sensor frames every 10 ms with the fuzzed frames after the third, until the
    loop says bye (or 10 s pass: a loaded machine may start the loop late); what the loop
    sent lands in ``got``."""
    conn, _ = server.accept()
    with conn:
        conn.settimeout(2)
        spec = {
            "robot": "cartpole",
            "env_id": "CartPole-v0",
            "control_dt": 0.01,
            "sensors": [{"name": n, "size": 1, "unit": "m", "kind": "jointpos"} for n in SIZES],
            "actuators": [{"name": "force", "low": -1.0, "high": 1.0}],
        }
        conn.sendall(wire.encode({"type": "hello", "version": 1, **spec}))
        reader = wire.FrameReader()
        try:
            deadline = time.monotonic() + 10.0
            for k in itertools.count():
                if time.monotonic() > deadline:
                    break
                readings = {n: np.zeros(1) for n in SIZES}
                conn.sendall(wire.encode(wire.sensors(k, 0.01 * k, -1, readings)))
                if k == 3:
                    conn.sendall(b"".join(_raw(b) for b in bodies))
                conn.settimeout(0.01)
                try:
                    got += reader.feed(conn.recv(1 << 16))
                except TimeoutError:
                    pass
                if any(m["type"] == "bye" for m in got):
                    return
        except OSError:  # the loop closed the link: what it sent first is still queued
            pass
        _drain(conn, reader, got)


def _drain(conn: socket.socket, reader: wire.FrameReader, got: list) -> None:
    """Read what is left in the robot's end of the link into ``got``: the frames the loop
    sent before it closed are still queued when the robot's own send failed first."""
    conn.settimeout(0.2)
    while True:
        try:
            data = conn.recv(1 << 16)
        except OSError:
            return
        if not data:
            return
        got += reader.feed(data)


def _loop_end(examples: int) -> None:
    @_settings(examples)
    @given(bodies=st.lists(BODIES, min_size=1, max_size=4))
    def check(bodies):
        server = socket.create_server(("127.0.0.1", 0))
        got: list = []
        thread = threading.Thread(target=_fuzzing_robot, args=(server, bodies, got))
        thread.start()
        link = TcpRobot(f"tcp://127.0.0.1:{server.getsockname()[1]}", timeout=2)
        try:
            link.connect()
            rec = loop.run(link, _Host(), _Policy(), loop.LoopOptions(seconds=0.1))
        finally:
            link.close()
            thread.join(5)
            server.close()
        holds = [m for m in got if m["type"] == "hold"]
        assert holds and holds[0]["reason"] == (rec.error or "done")[:200]
        assert rec.error is None or "\n" not in rec.error
        assert not (rec.error or "").startswith("unexpected")  # every fault was foreseen

    check()


@pytest.mark.parametrize(
    "examples", [15, pytest.param(200, marks=pytest.mark.full)], ids=["quick", "long"]
)
def test_loop_holds_the_robot_whatever_it_sends(examples):
    _loop_end(examples)


@pytest.mark.full
def test_robot_process_serves_on_after_frames_that_used_to_end_it():
    """``jaxenvs robot``: connections sending the frames that used to end the process
    (a 400-digit number, nesting 200,000 deep, a 5,000-digit seq) and a lost framing; the
    same process then serves a loop as usual."""
    import os
    import subprocess
    import sys
    from pathlib import Path

    root = Path(__file__).resolve().parents[2]
    robot = subprocess.Popen(
        [sys.executable, "-m", "jaxenvs", "robot", "CartPole-v0", "--listen", "tcp://127.0.0.1:0"],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        env={**os.environ, "PYTHONPATH": str(root)},
    )
    killers = [
        b'{"type":"command","seq":1,"action":[' + b"1" * 400 + b"]}",
        b"[" * 200_000 + b"]" * 200_000,
        b'{"type":"command","seq":' + b"5" * 5000 + b',"action":[0]}',
    ]
    try:
        assert robot.stdout is not None
        address = robot.stdout.readline().strip().removeprefix("listening on ")
        port = int(address.rsplit(":", 1)[1])
        for stream in [b"".join(_raw(k) for k in killers), (2**31).to_bytes(4, "big")]:
            with socket.create_connection(("127.0.0.1", port)) as sock:
                sock.sendall(stream)
                time.sleep(0.3)
            assert robot.poll() is None, robot.communicate()[1]
        link = TcpRobot(address)
        link.connect()
        end = time.monotonic() + 5
        while link.latest() is None and time.monotonic() < end:
            time.sleep(0.01)
        assert link.latest() is not None
        link.close()
        time.sleep(0.3)
        assert robot.poll() is None
    finally:
        robot.terminate()
        _, err = robot.communicate(timeout=10)
    assert "Traceback" not in err and "malformed" in err, err
