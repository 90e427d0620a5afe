"""``jaxenvs robot ID --listen tcp://HOST:PORT``: a task's robot simulated in MuJoCo C,
in real time, behind the TCP link of :mod:`jaxenvs.deploy.wire`.

The physics is ``mujoco.mj_step`` on the task's host model (its default params applied),
paced by the wall clock at the physics rate (one ``mj_step`` per ``timestep`` seconds).
Every control period (``substeps`` physics steps) it evaluates the MJCF's sensors at the
current state (``mj_forward``), adds Gaussian noise of ``noise`` times
:data:`~jaxenvs.robots.interface.NOISE_STD` of each sensor's unit, and publishes a
``sensors`` message and a privileged ``state`` message (the ground truth, for logging,
rendering and the task's return; a real robot sends none). It applies the newest valid
command through the robot's command map; with no valid command for ``watchdog``
control periods, or after a ``hold``, it holds (action 0: zero force for a motor, the
neutral pose for position servos). ``latency_ms`` delays each
message in both directions, plus a uniform ``[0, jitter_ms]`` (so messages may arrive
out of order, as on a real network). Bad messages are counted by reason and never stop it
(nor the listener: a connection that fails in any way is closed and the next one served).

With a key (``jaxenvs robot --key-file FILE``) each connection starts with the challenge
of :mod:`jaxenvs.deploy.auth`: a client that does not prove it holds the key within
:data:`~jaxenvs.deploy.auth.AUTH_TIMEOUT` s gets a ``bye`` and no sensor frame, and none of
its commands is applied. Without a key the robot listens only on a loopback address,
unless told otherwise (``insecure``).

JAX runs only while the world is built (the task's model, default params and initial
states drawn by the task's own ``reset``); the real-time loop is MuJoCo and numpy.

One client at a time; each connection starts a new episode from the next initial state.
"""

from __future__ import annotations

import contextlib
import copy
import heapq
import itertools
import select
import socket
import sys
import time
from collections import Counter
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import mujoco
import numpy as np

from jaxenvs.deploy import auth, wire
from jaxenvs.robots.interface import NOISE_STD, RobotSpec

#: initial states drawn when the world is built (connection k starts from state k mod this)
STARTS = 16


@dataclass
class World:
    """A task's robot on the host: model, spec, initial states, sensor slices."""

    model: mujoco.MjModel
    spec: RobotSpec
    substeps: int
    starts: list[dict[str, np.ndarray]]
    slices: dict[str, tuple[int, int]]
    ctrl_low: np.ndarray
    ctrl_high: np.ndarray


def build_world(env_id: str, seed: int = 0, overrides: Mapping[str, Any] | None = None) -> World:
    """The world of ``env_id``'s robot: the task's host physics model with its default
    params, sensors on, and :data:`STARTS` initial states of the task's ``reset``; the
    task's config with ``overrides`` (a terrain task's tile: ``jaxenvs robot --terrain``)."""
    import jax

    import jaxenvs
    from jaxenvs.robots.interface import spec_of

    env = jaxenvs.make(env_id, physics="c", **dict(overrides or {}))
    spec = spec_of(env, env_id)
    model = copy.deepcopy(env.sim.physics_mj_model)
    for name, value in env.default_params.model.items():
        getattr(model, name)[...] = np.asarray(value).reshape(getattr(model, name).shape)
    model.opt.disableflags &= ~int(mujoco.mjtDisableBit.mjDSBL_SENSOR)
    states = jax.vmap(env.reset)(jax.random.split(jax.random.key(seed), STARTS)).data
    pose = {k: np.asarray(getattr(states, k), np.float64) for k in ("qpos", "qvel", "mocap_pos")}
    starts = [{k: v[i] for k, v in pose.items()} for i in range(STARTS)]
    slices = {}
    for s in spec.sensors:
        sensor = model.sensor(s.name)
        slices[s.name] = (int(sensor.adr[0]), int(sensor.dim[0]))
    low = np.asarray([a.low for a in spec.actuators], np.float64)
    high = np.asarray([a.high for a in spec.actuators], np.float64)
    return World(model, spec, env.sim.substeps, starts, slices, low, high)


@dataclass(frozen=True)
class LinkOptions:
    """How the simulated link misbehaves, and when the robot holds on its own.

    Attributes:
      noise: sensor noise std as a multiple of NOISE_STD.
      latency_ms, jitter_ms: each message's delay, plus uniform [0, jitter].
      watchdog: control periods without a valid command before the robot holds.
      seconds: stop after this long (0: serve until the client leaves or forever).
      once: exit when the first client leaves.
      seed: seeds the noise and the delays.
    """

    noise: float = 0.0
    latency_ms: float = 0.0
    jitter_ms: float = 0.0
    watchdog: int = 5
    seconds: float = 0.0
    once: bool = False
    seed: int = 0


class _Episode:
    """One connection's run: physics state, the commands in force, the outgoing queue."""

    def __init__(self, world: World, start: dict[str, np.ndarray], conn: socket.socket) -> None:
        self.world, self.conn = world, conn
        self.data = mujoco.MjData(world.model)
        self.data.qpos[:], self.data.qvel[:] = start["qpos"], start["qvel"]
        if world.model.nmocap:
            self.data.mocap_pos[:] = start["mocap_pos"]
        mujoco.mj_forward(world.model, self.data)
        self.counts: Counter[str] = Counter()
        self.reader = wire.FrameReader(self.counts)
        self.last_cmd, self.acked, self.last_cmd_step = -1, -1, 0
        self.held = False
        self.steps = 0
        self.frames = 0
        self.outbox: list[tuple[float, int, bytes]] = []  # (due, tiebreak, frame)
        self.inbox: list[tuple[float, int, dict[str, Any]]] = []
        self._tie = itertools.count()
        self.closed = ""
        #: the client did not prove it holds the key (nothing was simulated)
        self.refused = False

    def ctrl_of(self, action: np.ndarray) -> np.ndarray:
        w = self.world
        return (w.ctrl_low + w.ctrl_high) / 2 + action * (w.ctrl_high - w.ctrl_low) / 2

    def readings(self, rng: np.random.Generator, noise: float) -> dict[str, np.ndarray]:
        mujoco.mj_forward(self.world.model, self.data)
        out = {}
        for s in self.world.spec.sensors:
            adr, dim = self.world.slices[s.name]
            value = self.data.sensordata[adr : adr + dim].copy()
            if noise > 0:
                value += rng.normal(0.0, noise * NOISE_STD.get(s.unit, 1e-2), dim)
            out[s.name] = value
        return out

    def handle(self, msg: dict[str, Any]) -> None:
        """Apply a valid command, hold on a hold, end on a bye; count anything else."""
        kind = msg.get("type")
        try:
            if kind == "command":
                seq, action = wire.parse_command(msg, len(self.world.spec.actuators), self.last_cmd)
                self.last_cmd, self.acked, self.held = seq, seq, False
                self.data.ctrl[:] = self.ctrl_of(action)
                self.last_cmd_step = self.frames
            elif kind == "hold":
                # its seq is above every command sent before it: one of those arriving
                # late (reordered by the link's jitter) is stale, and cannot undo the hold
                held_at = msg.get("seq")
                if isinstance(held_at, int) and not isinstance(held_at, bool):
                    self.last_cmd = max(self.last_cmd, held_at)
                self.hold()
            elif kind == "bye":
                self.closed = "bye"
            else:
                self.counts["malformed"] += 1
        except wire.BadMessage as bad:
            self.counts[bad.reason] += 1
        except (ValueError, TypeError, OverflowError, RecursionError):
            self.counts["malformed"] += 1  # a message the parsers missed: counted, never fatal

    def hold(self) -> None:
        """Action 0 on every actuator: zero force for a motor with a centred range, the
        neutral pose for position servos (the hexapod's standing pose)."""
        self.held = True
        self.data.ctrl[:] = self.ctrl_of(np.zeros(len(self.world.spec.actuators)))

    def send_now(self, frame: bytes) -> None:
        try:
            self.conn.sendall(frame)
        except OSError:
            self.closed = self.closed or "link lost"


def _delay(rng: np.random.Generator, opts: LinkOptions) -> float:
    return (opts.latency_ms + rng.uniform(0.0, opts.jitter_ms)) / 1e3


def _publish(ep: _Episode, rng: np.random.Generator, opts: LinkOptions, t: float) -> None:
    readings = ep.readings(rng, opts.noise)
    d = ep.data
    frames = [
        wire.encode(wire.sensors(ep.frames, d.time, ep.acked, readings)),
        wire.encode(wire.state(ep.frames, d.time, d.qpos, d.qvel, d.mocap_pos)),
    ]
    due = t + _delay(rng, opts)
    for frame in frames:
        heapq.heappush(ep.outbox, (due, next(ep._tie), frame))


def _receive(ep: _Episode, rng: np.random.Generator, opts: LinkOptions, now: float) -> None:
    try:
        data = ep.conn.recv(1 << 16)
    except (BlockingIOError, InterruptedError):
        return
    except OSError:
        data = b""
    if not data:
        ep.closed = ep.closed or "the client closed the link"
        return
    try:
        messages = ep.reader.feed(data)
    except wire.FramingError as err:
        ep.counts["malformed"] += 1
        ep.closed = f"framing lost ({err})"
        return
    for msg in messages:
        heapq.heappush(ep.inbox, (now + _delay(rng, opts), next(ep._tie), msg))


def _hello(world: World, mac: str | None) -> bytes:
    hello = {"type": "hello", "version": wire.VERSION, "privileged": True, **world.spec.to_json()}
    return wire.encode(hello if mac is None else {**hello, "mac": mac})


def _first(conn: socket.socket, reader: wire.FrameReader, end: float) -> dict[str, Any] | str:
    """The client's first message before ``end`` (a monotonic time), or why none came."""
    while True:
        left = end - time.monotonic()
        if left <= 0:
            return f"no answer to the challenge within {auth.AUTH_TIMEOUT:g} s"
        conn.settimeout(left)
        try:
            data = conn.recv(1 << 16)
        except TimeoutError:
            continue
        except OSError:
            return "link lost"
        if not data:
            return "the client left"
        try:
            messages = reader.feed(data)
        except wire.FramingError:
            return "framing lost"
        if messages:
            return messages[0]


def answer_challenge(conn: socket.socket, key: bytes, reader: wire.FrameReader) -> str | dict:
    """The robot's side of the handshake (:mod:`jaxenvs.deploy.auth`) on a blocking
    ``conn``: send a challenge, read the answer; the hello's ``mac`` when the client proved
    it holds ``key``, else ``{"refused": why}``."""
    robot_nonce = auth.nonce()
    challenge = {"type": "challenge", "version": wire.VERSION, "nonce": robot_nonce}
    try:
        conn.sendall(wire.encode(challenge))
    except OSError:  # a client gone before the challenge proved nothing: refused
        return {"refused": "link lost"}
    msg = _first(conn, reader, time.monotonic() + auth.AUTH_TIMEOUT)
    if isinstance(msg, str):
        return {"refused": msg}
    client_nonce = msg.get("nonce")
    if (
        msg.get("type") != "auth"
        or not auth.valid_nonce(client_nonce)
        or not auth.verify(key, "loop", robot_nonce, client_nonce, msg.get("mac"))
    ):
        return {"refused": auth.REFUSED}
    return auth.proof(key, "robot", client_nonce, robot_nonce)


def run_episode(
    world: World, conn: socket.socket, start: dict, opts: LinkOptions, key: bytes | None = None
) -> _Episode:
    """Simulate in real time for one client until it leaves (or ``opts.seconds``); with a
    ``key``, only after the client proved it holds it (else ``closed`` says why, and
    ``refused`` is set)."""
    rng = np.random.default_rng(opts.seed)
    ep = _Episode(world, start, conn)
    mac = None
    if key is not None:
        answer = answer_challenge(conn, key, ep.reader)
        if isinstance(answer, dict):
            ep.closed, ep.refused = answer["refused"], True
            ep.send_now(wire.encode({"type": "bye", "reason": ep.closed}))
            return ep
        mac = answer
    conn.setblocking(False)
    dt = float(world.model.opt.timestep)
    t0 = time.monotonic()
    ep.send_now(_hello(world, mac))
    _publish(ep, rng, opts, t0)
    next_step = t0 + dt
    while not ep.closed:
        now = time.monotonic()
        while ep.outbox and ep.outbox[0][0] <= now:
            ep.send_now(heapq.heappop(ep.outbox)[2])
        while ep.inbox and ep.inbox[0][0] <= now:
            ep.handle(heapq.heappop(ep.inbox)[2])
        if now >= next_step:
            mujoco.mj_step(world.model, ep.data)
            ep.steps += 1
            next_step += dt
            if now - next_step > 5 * dt:  # the host fell behind: keep time, count it
                ep.counts["physics_overrun"] += 1
                next_step = now + dt
            if ep.steps % world.substeps == 0:
                ep.frames += 1
                if not ep.held and ep.frames - ep.last_cmd_step > opts.watchdog:
                    ep.counts["watchdog_hold"] += 1
                    ep.hold()
                _publish(ep, rng, opts, now)
            if opts.seconds and now - t0 >= opts.seconds:
                ep.closed = "time is up"
            continue
        due = [next_step] + [q[0][0] for q in (ep.outbox, ep.inbox) if q]
        readable, _, _ = select.select([conn], [], [], max(0.0, min(due) - now))
        if readable:
            _receive(ep, rng, opts, now)
    ep.hold()
    ep.send_now(wire.encode({"type": "bye", "reason": ep.closed, "counts": dict(ep.counts)}))
    return ep


def parse_address(address: str) -> tuple[str, int]:
    """``tcp://HOST:PORT`` -> ``(host, port)``; ``ValueError`` naming a bad address."""
    scheme, sep, rest = address.partition("://")
    host, colon, port = rest.rpartition(":")
    if scheme != "tcp" or not sep or not colon or not host or not port.isdigit():
        raise ValueError(f"bad address {address!r}: expected tcp://HOST:PORT")
    if int(port) > 65535:
        raise ValueError(f"bad address {address!r}: port out of range")
    return host.strip("[]"), int(port)


def check_listen(address: str, key: bytes | None, insecure: bool = False) -> None:
    """``ValueError`` (one line naming ``--key-file``) for listening on ``address`` beyond
    this computer without a key, unless ``insecure``."""
    host, _ = parse_address(address)
    if key is None and not insecure and not auth.is_loopback(host):
        raise ValueError(
            f"listening on {host} without a key lets anyone who reaches the port drive the "
            "robot: give --key-file FILE (or --insecure to allow it)"
        )


def _serve_one(
    world: World, conn: socket.socket, start: dict, opts: LinkOptions, key: bytes | None
) -> _Episode:
    """One connection, whatever it sends; a failure the episode did not expect ends the
    connection (held, counted as ``internal_error``), never the listener."""
    try:
        with contextlib.suppress(OSError):  # a client already gone: the episode says so
            conn.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        return run_episode(world, conn, start, opts, key)
    except Exception as err:  # noqa: BLE001 (the listener outlives any one client)
        ep = _Episode(world, start, conn)
        ep.counts["internal_error"] += 1
        ep.closed = f"{type(err).__name__}: {str(err)[:120]}"
        return ep


def serve(
    world: World,
    address: str,
    opts: LinkOptions,
    key: bytes | None = None,
    insecure: bool = False,
) -> int:
    """Listen at ``address`` (beyond the loopback only with a ``key``, or ``insecure``:
    :func:`check_listen`); print ``listening on tcp://HOST:PORT`` (the bound port) and one
    line per finished connection; return 0. With ``opts.once``, return when the first
    client that proved the key (any client, without a key) leaves."""
    check_listen(address, key, insecure)
    host, port = parse_address(address)
    with socket.create_server((host, port)) as server:
        bound = server.getsockname()
        print(f"listening on tcp://{bound[0]}:{bound[1]}", flush=True)
        served = 0
        while True:
            try:
                conn, peer = server.accept()
            except ConnectionAbortedError:  # the client left before it was accepted
                continue
            with conn:
                ep = _serve_one(world, conn, world.starts[served % len(world.starts)], opts, key)
            if ep.refused:
                print(
                    f"robot {world.spec.robot}: refused {peer[0]}: {ep.closed}",
                    file=sys.stderr,
                    flush=True,
                )
                continue
            served += 1
            bad = ", ".join(f"{n} {r}" for r, n in sorted(ep.counts.items())) or "none"
            print(
                f"robot {world.spec.robot}: {ep.frames} control steps for {peer[0]}, "
                f"ended: {ep.closed}; bad or late messages: {bad}",
                file=sys.stderr,
                flush=True,
            )
            if opts.once:
                break
    return 0


__all__ = [
    "STARTS",
    "LinkOptions",
    "World",
    "answer_challenge",
    "build_world",
    "check_listen",
    "parse_address",
    "run_episode",
    "serve",
]
