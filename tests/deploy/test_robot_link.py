"""The robot link: the message codec, the robot interface (spec, the task's observation of
readings on the host) and the simulated robot's episode over a socket pair."""

from __future__ import annotations

import json
import socket
import struct
import threading

import jax
import numpy as np
import pytest

import jaxenvs
from jaxenvs.deploy import simrobot, wire
from jaxenvs.robots.hexapod import Hexapod
from jaxenvs.robots.interface import HostTask, RobotLink, RobotSpec, spec_of


def _raw(body: bytes) -> bytes:
    return struct.pack(">I", len(body)) + body


# ------------------------------------------------------------------------------ the codec
def test_codec_round_trip_byte_by_byte():
    readings = {"a": np.array([1.5]), "b": np.array([0.0, -2.0, 3.25])}
    frames = [
        wire.encode(wire.sensors(7, 0.14, 6, readings)),
        wire.encode(wire.command(3, np.array([0.5, -1.0]))),
        wire.encode(wire.state(7, 0.14, [0.1, 0.2], [0.3, 0.4], np.zeros((1, 3)))),
    ]
    reader, got = wire.FrameReader(), []
    for byte in b"".join(frames):
        got += reader.feed(bytes([byte]))
    assert [m["type"] for m in got] == ["sensors", "command", "state"]
    seq, stamp, acked, out = wire.parse_sensors(got[0], {"a": 1, "b": 3}, 6)
    assert (seq, stamp, acked) == (7, 0.14, 6)
    assert all(np.array_equal(out[k], readings[k]) for k in readings)
    seq, action = wire.parse_command(got[1], 2, -1)
    assert seq == 3 and action.tolist() == [0.5, -1.0]
    seq, state = wire.parse_state(got[2], 2, 2, 1, -1)
    assert seq == 7 and state["qpos"].tolist() == [0.1, 0.2] and state["mocap_pos"].shape == (1, 3)
    assert not reader.counts


def test_malformed_frames_are_counted_and_the_stream_goes_on():
    reader = wire.FrameReader()
    good = wire.encode(wire.command(1, np.zeros(1)))
    stream = _raw(b"{not json") + _raw(b"[1, 2]") + _raw(b'{"no": "type"}') + good
    got = reader.feed(stream)
    assert [m["seq"] for m in got] == [1]
    assert reader.counts["malformed"] == 3
    with pytest.raises(wire.FramingError, match="out of range"):
        wire.FrameReader().feed(struct.pack(">I", wire.MAX_FRAME + 1) + b"x")


@pytest.mark.parametrize(
    ("body", "reason"),
    [
        (b'{"type":"command","seq":5,"action":[0.1]}', "wrong_size"),
        (b'{"type":"command","seq":5,"action":[NaN, 0.0]}', "non_finite"),
        (b'{"type":"command","seq":2,"action":[0.1, 0.0]}', "stale"),
        (b'{"type":"command","seq":5,"action":[1.5, 0.0]}', "out_of_range"),
        (b'{"type":"command","seq":"5","action":[0.1, 0.0]}', "malformed"),
        (b'{"type":"command","seq":5,"action":"fast"}', "malformed"),
    ],
)
def test_bad_commands_name_their_reason(body, reason):
    (msg,) = wire.FrameReader().feed(_raw(body))
    with pytest.raises(wire.BadMessage) as err:
        wire.parse_command(msg, 2, last_seq=2)
    assert err.value.reason == reason


def test_encode_refuses_non_finite_numbers():
    with pytest.raises(ValueError):
        wire.encode(wire.command(1, np.array([np.nan])))


# ---------------------------------------------------------------------- the robot interface
def test_spec_of_cartpole_and_reacher():
    spec = spec_of(jaxenvs.make("CartPole-v0", physics="c"), "CartPole-v0")
    units = {s.name: s.unit for s in spec.sensors}
    assert units == {
        "slider_pos": "m",
        "hinge_pos": "rad",
        "slider_vel": "m/s",
        "hinge_vel": "rad/s",
    }
    assert [(a.name, a.low, a.high) for a in spec.actuators] == [("force", -1.0, 1.0)]
    assert spec.control_dt == pytest.approx(0.02) and spec.robot == "cartpole"
    reacher = spec_of(jaxenvs.make("Reacher-v0", physics="c"), "Reacher-v0")
    assert len(reacher.actuators) == 2 and {s.size for s in reacher.sensors} == {1}
    assert RobotSpec.from_json(json.loads(json.dumps(spec.to_json()))) == spec
    with pytest.raises(ValueError, match="cartpole"):
        spec.check_matches(reacher)


def test_spec_leaves_out_privileged_sensors():
    robot = Hexapod()
    assert robot.privileged, "the hexapod declares privileged sensors"

    class Task:
        control_dt = 0.02

    task = Task()
    task.robot = robot  # type: ignore[attr-defined]
    names = {s.name for s in spec_of(task, "HexapodWalk-v0").sensors}
    assert names and not names & set(robot.privileged)


def test_bad_hello_is_one_line():
    with pytest.raises(ValueError, match="bad robot description"):
        RobotSpec.from_json({"robot": "x", "env_id": "y", "sensors": [{}], "actuators": []})


@pytest.mark.parametrize("env_id", ["CartPole-v0", "Reacher-v0"])
def test_host_observation_is_the_simulators(env_id):
    """The observation the loop computes from readings (and, for Reacher, the task state
    of the ground truth) equals the env's own, on the C engine."""
    env = jaxenvs.make(env_id, physics="c")
    host = HostTask(env, seed=0)
    for seed in range(3):
        state = env.reset(jax.random.key(seed))
        readings = {k: np.asarray(v) for k, v in env.robot.sense(state.data).items()}
        truth = {k: np.asarray(getattr(state.data, k)) for k in ("qpos", "qvel", "mocap_pos")}
        task, _, terminated = host.of_truth(truth, truth, host.zero_action)
        obs = host.observe(readings, task)
        np.testing.assert_allclose(obs, np.asarray(state.obs), rtol=0, atol=1e-6)
        assert not terminated


def test_tcp_robot_is_a_robot_link():
    from jaxenvs.deploy.link import TcpRobot

    assert isinstance(TcpRobot("tcp://127.0.0.1:1"), RobotLink)


# ------------------------------------------------------------------------ the simulated robot
@pytest.fixture(scope="module")
def world():
    return simrobot.build_world("CartPole-v0", seed=0)


def _episode(world, opts, client):
    """Run one episode on a socket pair with ``client(sock)`` on the other end."""
    ours, theirs = socket.socketpair()
    result = {}
    thread = threading.Thread(
        target=lambda: result.update(ep=simrobot.run_episode(world, ours, world.starts[0], opts))
    )
    thread.start()
    try:
        client(theirs)
    finally:
        thread.join(10)
        ours.close()
        theirs.close()
    assert not thread.is_alive()
    return result["ep"]


def _read_until(sock, reader, kind, n=1):
    got = []
    while len([m for m in got if m["type"] == kind]) < n:
        data = sock.recv(1 << 16)
        assert data, "the robot closed the link"
        got += reader.feed(data)
    return got


@pytest.mark.full
def test_sim_robot_counts_bad_messages_and_keeps_running(world):
    """Garbage, wrong sizes, NaN, stale and out-of-range commands are counted; valid ones
    are applied and acknowledged; the robot publishes at the control rate throughout."""

    def client(sock):
        reader = wire.FrameReader()
        hello = _read_until(sock, reader, "hello")[0]
        assert RobotSpec.from_json(hello) == world.spec and hello["privileged"] is True
        sock.sendall(wire.encode(wire.command(5, np.array([1.0]))))
        sock.sendall(_raw(b"garbage") + _raw(b'{"type":"command","seq":9,"action":[NaN]}'))
        sock.sendall(_raw(b'{"type":"command","seq":9,"action":[0.5, 0.5]}'))
        sock.sendall(wire.encode(wire.command(4, np.array([-1.0]))))  # stale
        sock.sendall(_raw(b'{"type":"dance"}'))
        frames = _read_until(sock, reader, "sensors", 10)
        acked = [m["acked"] for m in frames if m["type"] == "sensors"]
        assert acked[-1] == 5
        sock.sendall(wire.encode({"type": "bye", "reason": "done"}))
        bye = _read_until(sock, reader, "bye")[-1]
        assert bye["counts"]["stale"] == 1

    ep = _episode(world, simrobot.LinkOptions(), client)
    assert ep.counts["malformed"] == 2 and ep.counts["non_finite"] == 1
    assert ep.counts["wrong_size"] == 1 and ep.counts["stale"] == 1
    assert ep.closed == "bye" and ep.frames >= 9 and ep.acked == 5


def test_sim_robot_holds_without_commands_and_paces_in_real_time(world):
    """No command for ``watchdog`` periods: the robot holds (zero command); its clock
    follows the wall clock."""
    import time

    def client(sock):
        reader = wire.FrameReader()
        _read_until(sock, reader, "hello")
        sock.sendall(wire.encode(wire.command(0, np.array([1.0]))))
        start = time.monotonic()
        frames = _read_until(sock, reader, "sensors", 25)
        elapsed = time.monotonic() - start
        stamps = [m["stamp"] for m in frames if m["type"] == "sensors"]
        assert stamps[-1] - stamps[0] == pytest.approx(elapsed, abs=0.1)
        sock.sendall(wire.encode({"type": "bye", "reason": "done"}))

    ep = _episode(world, simrobot.LinkOptions(watchdog=3), client)
    assert ep.counts["watchdog_hold"] == 1 and ep.held and ep.data.ctrl[0] == 0.0


def test_parse_address():
    assert simrobot.parse_address("tcp://127.0.0.1:0") == ("127.0.0.1", 0)
    for bad in ("127.0.0.1:5", "udp://h:1", "tcp://h:", "tcp://h:99999"):
        with pytest.raises(ValueError, match="bad address"):
            simrobot.parse_address(bad)


@pytest.mark.parametrize(
    ("env_id", "needs", "shape"), [("CartPole-v0", False, ()), ("Reacher-v0", True, (2,))]
)
def test_host_task_says_whether_the_observation_needs_a_task_input(env_id, needs, shape):
    """Reacher's observation needs its target (the ground truth's, or --command); CartPole's
    nothing beyond the readings."""
    env = jaxenvs.make(env_id, physics="c")
    host = HostTask(env)
    model = env.sim.physics_mj_model
    truth = {
        "qpos": model.qpos0.copy(),
        "qvel": np.zeros(model.nv),
        "mocap_pos": np.zeros((model.nmocap, 3)),
    }
    assert host.warm(spec_of(env, env_id).sizes(), truth) == shape
    assert host.needs_input is needs


def test_spec_command_ends_give_the_robots_command_map(world):
    """The spec's low/high (the robot's command map at -1, +1) and the simulated robot's
    linear map between them give the robot's own ``command`` of any action."""
    from jaxenvs.robots.cartpole import Cartpole

    actions = np.random.default_rng(0).uniform(-1, 1, (5, 18)).astype(np.float32)

    class Task:
        control_dt = 0.05

    for robot in (Hexapod(), Cartpole()):
        task = Task()
        task.robot = robot  # type: ignore[attr-defined]
        spec = spec_of(task, "X")
        low = np.array([a.low for a in spec.actuators])
        high = np.array([a.high for a in spec.actuators])
        for a in actions[:, : len(low)]:
            linear = (low + high) / 2 + a * (high - low) / 2
            np.testing.assert_allclose(linear, np.asarray(robot.command(a)), atol=1e-6)
    ep = simrobot._Episode(world, world.starts[0], None)
    np.testing.assert_allclose(ep.ctrl_of(np.array([0.3])), [0.3], atol=1e-12)


def test_a_spec_checks_every_declared_field_actuator_limits_included():
    """A robot declaring other actuator limits (100x the task's force), a size of 1e400 or
    a NaN control period is refused in one line by the spec itself."""
    import dataclasses

    spec = spec_of(jaxenvs.make("CartPole-v0"), "CartPole-v0")
    wide = dataclasses.replace(
        spec,
        actuators=tuple(
            dataclasses.replace(a, low=100 * a.low, high=100 * a.high) for a in spec.actuators
        ),
    )
    with pytest.raises(ValueError, match="actuator .* takes"):
        spec.check_matches(wide)
    nan = dataclasses.replace(spec, control_dt=float("nan"))
    with pytest.raises(ValueError, match="control period"):
        spec.check_matches(nan)
    hello = spec.to_json()
    hello["sensors"][0]["size"] = 1e400
    with pytest.raises(ValueError, match="bad robot description"):
        RobotSpec.from_json(hello)


def test_a_command_arriving_after_the_hold_sent_after_it_is_stale(world):
    """The link's jitter can deliver a command after the hold the loop sent after it (the
    hold's seq is above every command's): the robot stays held, the command counted
    stale (it used to be applied, driving the robot again)."""
    ep = simrobot._Episode(world, world.starts[0], None)
    ep.handle(wire.command(0, np.array([1.0])))
    ep.handle({"type": "hold", "seq": 2, "reason": "policy not finite"})
    ep.handle(wire.command(1, np.array([1.0])))  # sent before the hold, arriving after it
    assert ep.held and ep.data.ctrl[0] == ep.ctrl_of(np.zeros(1))[0]
    assert ep.counts["stale"] == 1
    ep.handle(wire.command(3, np.array([0.5])))  # a newer command still drives it
    assert not ep.held and ep.data.ctrl[0] == pytest.approx(ep.ctrl_of(np.array([0.5]))[0])
