""":class:`TcpRobot`: the :class:`~jaxenvs.robots.interface.RobotLink` of a robot that
speaks :mod:`jaxenvs.deploy.wire` over TCP (the simulated robot of ``jaxenvs robot``, or
your robot's firmware or bridge).

On the loop's side a message that is malformed, of the wrong size or not finite, or a
sensor frame acknowledging a command never sent, ends the run
(:class:`~jaxenvs.robots.interface.LinkError` naming the fault): the loop then holds and
exits. Sensor frames older than the newest (reordered by the network) are counted as
``stale`` and dropped.

:meth:`TcpRobot.connect` raises ``ValueError`` (a robot that is not the one asked for,
as a mismatch of the spec is) for a hello that describes no valid robot, and on a keyed
link (:mod:`jaxenvs.deploy.auth`) for a robot that refuses the key, asks for one when
none was given, asks for none when one was, or does not prove it holds it.
"""

from __future__ import annotations

import math
import socket
import time
from collections import Counter
from typing import Any

import numpy as np

from jaxenvs.deploy import auth, wire
from jaxenvs.deploy.simrobot import parse_address
from jaxenvs.robots.interface import LinkError, RobotSpec, SensorFrame

#: how long one poll of the link goes on reading once it has read something (s): what
#: arrives faster waits in the socket for the next poll
POLL_SECONDS = 0.005


class TcpRobot:
    """A robot at ``tcp://HOST:PORT`` (see the module docstring).

    Attributes:
      counts: bad or late messages received, by reason.
      robot_counts: the robot's own counts of bad messages (from its ``bye``).
      privileged: the robot also sends ground-truth ``state`` messages.
    """

    def __init__(self, address: str, timeout: float = 10.0, key: bytes | None = None) -> None:
        self.address = address
        self.key = key
        self.host, self.port = parse_address(address)
        self.timeout = timeout
        self.sock: socket.socket | None = None
        self.counts: Counter[str] = Counter()
        self.reader = wire.FrameReader(self.counts)
        self.robot_counts: dict[str, int] = {}
        self.spec: RobotSpec | None = None
        self.privileged = False
        self._latest: SensorFrame | None = None
        self._truth: tuple[int, dict[str, np.ndarray]] | None = None
        self._new_truths: list[tuple[int, dict[str, np.ndarray]]] = []
        self._sizes: dict[str, int] = {}
        self._dims: tuple[int, int, int] = (0, 0, 0)
        self._ended = ""
        self._sent = -1  # the last command's seq
        self._pending: list[dict[str, Any]] = []  # decoded before the hello was handled

    # ------------------------------------------------------------------ the protocol
    def connect(self) -> RobotSpec:
        """Connect, prove the key when the robot asks (:mod:`jaxenvs.deploy.auth`), read
        the robot's hello (each within ``timeout`` s) and return its spec."""
        try:
            sock = socket.create_connection((self.host, self.port), timeout=self.timeout)
        except OSError as err:
            raise LinkError(f"cannot connect to {self.address}: {err.strerror or err}") from None
        sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        self.sock = sock
        hello = self._handshake(self._first_message())
        try:
            self.spec = RobotSpec.from_json(hello)
        except ValueError as err:  # (an integer field given as a huge float included)
            raise ValueError(f"{self.address}: {err}") from None
        self.privileged = hello.get("privileged", False) is True
        self._sizes = self.spec.sizes()
        sock.setblocking(False)
        return self.spec

    def _handshake(self, first: dict[str, Any]) -> dict[str, Any]:
        """The hello, after the challenge-response when the robot asks for the key."""
        if first.get("type") == "challenge":
            if self.key is None:
                raise ValueError(f"the robot at {self.address} asks for a key: give --key-file")
            robot_nonce = first.get("nonce")
            if first.get("version") != wire.VERSION or not auth.valid_nonce(robot_nonce):
                raise LinkError(f"{self.address} sent a malformed challenge")
            ours = auth.nonce()
            mac = auth.proof(self.key, "loop", robot_nonce, ours)
            self._send({"type": "auth", "nonce": ours, "mac": mac})
            hello = self._first_message()
            if hello.get("type") == "bye" and hello.get("reason") == auth.REFUSED:
                raise ValueError(f"the robot at {self.address} refused the key (not its key?)")
            self._check_hello(hello)
            if not auth.verify(self.key, "robot", ours, robot_nonce, hello.get("mac")):
                raise ValueError(f"the robot at {self.address} did not prove it holds the key")
            return hello
        self._check_hello(first)
        if self.key is not None:
            raise ValueError(
                f"the robot at {self.address} asks for no key (start it with --key-file, or "
                "give none)"
            )
        return first

    def _check_hello(self, hello: dict[str, Any]) -> None:
        if hello.get("type") != "hello":
            raise LinkError(f"{self.address} did not say hello (version {wire.VERSION})")
        if hello.get("version") != wire.VERSION:
            raise ValueError(
                f"{self.address} speaks version {str(hello.get('version'))[:20]} of the "
                f"link, this is version {wire.VERSION}"
            )

    def set_state_sizes(self, nq: int, nv: int, nmocap: int) -> None:
        """The sizes of the privileged state messages (the task's model)."""
        self._dims = (nq, nv, nmocap)

    def latest(self) -> SensorFrame | None:
        self._poll()
        return self._latest

    def truths(self) -> list[tuple[int, dict[str, np.ndarray]]]:
        """The privileged ground truths ``(seq, {"qpos", "qvel", "mocap_pos"})`` received
        since the last call, oldest first."""
        out, self._new_truths = self._new_truths, []
        return out

    def send(self, seq: int, action: np.ndarray) -> None:
        self._send(wire.command(seq, action))
        self._sent = max(self._sent, int(seq))

    def hold(self, reason: str) -> None:
        """Best effort: a hold message, its ``seq`` above every command's (the robot also
        holds on its own watchdog)."""
        try:
            self._send({"type": "hold", "seq": self._sent + 1, "reason": reason[:200]})
        except LinkError:
            pass

    def close(self, wait: float = 0.3) -> None:
        """Say bye, collect the robot's bye (its counts) for up to ``wait`` s, close."""
        if self.sock is None:
            return
        try:
            self._send({"type": "bye", "reason": "done"})
            end = time.monotonic() + wait
            while not self._ended and time.monotonic() < end:
                try:
                    self._poll(block=end - time.monotonic())
                except LinkError:
                    break
        except LinkError:
            pass
        finally:
            self.sock.close()
            self.sock = None

    # ------------------------------------------------------------------ internals
    def _send(self, message: dict[str, Any]) -> None:
        if self.sock is None:
            raise LinkError("the link is closed")
        try:
            self.sock.sendall(wire.encode(message))
        except OSError as err:
            raise LinkError(f"link lost while sending ({err.strerror or err})") from None

    def _feed(self, data: bytes) -> list[dict[str, Any]]:
        """Decode ``data``; :class:`LinkError` naming the fault for a malformed frame."""
        before = self.counts["malformed"]
        try:
            messages = self.reader.feed(data)
        except wire.FramingError as err:
            self.counts["malformed"] += 1
            raise LinkError(f"malformed message from the robot ({err})") from None
        if self.counts["malformed"] > before:
            raise LinkError(f"malformed message from the robot ({self.reader.last_bad})")
        return messages

    def _first_message(self) -> dict[str, Any]:
        """The next message (within ``timeout`` s); later ones of the same read wait in
        ``_pending``."""
        assert self.sock is not None
        end = time.monotonic() + self.timeout
        while not self._pending:
            left = end - time.monotonic()
            if left <= 0:
                raise LinkError(f"no hello from {self.address} within {self.timeout:g} s")
            self.sock.settimeout(left)
            try:
                data = self.sock.recv(1 << 16)
            except TimeoutError:
                continue
            except OSError as err:
                raise LinkError(f"link lost before hello ({err.strerror or err})") from None
            if not data:
                raise LinkError(f"{self.address} closed the link before its hello")
            self._pending += self._feed(data)
        return self._pending.pop(0)

    def _poll(self, block: float = 0.0) -> None:
        """Read what has arrived (waiting up to ``block`` s for the first bytes), for at
        most :data:`POLL_SECONDS` after the first read: a robot that floods the link
        cannot keep the caller from its own deadlines (the loop's sensor timeout,
        ``close``'s wait)."""
        assert self.sock is not None
        pending, self._pending = self._pending, []
        for msg in pending:
            self._handle(msg, time.monotonic())
        self.sock.settimeout(block if block > 0 else 0.0)
        until = math.inf
        while time.monotonic() < until:
            try:
                data = self.sock.recv(1 << 16)
            except (BlockingIOError, TimeoutError, InterruptedError):
                return
            except ConnectionResetError:
                raise LinkError("the robot closed the link (connection reset)") from None
            except OSError as err:
                raise LinkError(f"link lost ({err.strerror or err})") from None
            if not data:
                if self._ended:
                    return
                raise LinkError("the robot closed the link")
            until = min(until, time.monotonic() + POLL_SECONDS)
            for msg in self._feed(data):
                self._handle(msg, time.monotonic())
            self.sock.settimeout(0.0)

    def _handle(self, msg: dict[str, Any], now: float) -> None:
        kind = msg["type"]
        try:
            if kind == "sensors":
                last = -1 if self._latest is None else self._latest.seq
                seq, stamp, acked, readings = wire.parse_sensors(msg, self._sizes, last)
                if acked > self._sent:
                    raise wire.BadMessage(
                        "out_of_range", f"acked {acked}, beyond the last command sent"
                    )
                self._latest = SensorFrame(seq, stamp, readings, now, acked)
            elif kind == "state":
                if self._dims == (0, 0, 0):
                    return
                last = -1 if self._truth is None else self._truth[0]
                self._truth = wire.parse_state(msg, *self._dims, last)
                self._new_truths.append(self._truth)
            elif kind == "bye":
                counts = msg.get("counts")
                self.robot_counts = (
                    {str(k): v for k, v in counts.items() if type(v) is int}
                    if isinstance(counts, dict)
                    else {}
                )
                self._ended = str(msg.get("reason", ""))[:200] or "bye"
            else:
                raise wire.BadMessage("malformed", f"unexpected message type {kind[:40]!r}")
        except wire.BadMessage as bad:
            self.counts[bad.reason] += 1
            if bad.reason != "stale":
                raise LinkError(f"malformed message from the robot ({bad})") from None

    @property
    def ended(self) -> str:
        """The robot's reason, once it said bye ('' before)."""
        return self._ended


__all__ = ["TcpRobot"]
