""":class:`TcpRobot`: the :class:`~jaxenvs.robots.interface.RobotLink` of a robot that
speaks :mod:`jaxenvs.deploy.wire` over TCP (the simulated robot of ``jaxenvs robot``, or
your robot's firmware or bridge).

On the loop's side a message that is malformed, of the wrong size or not finite ends the
run (:class:`~jaxenvs.robots.interface.LinkError`): the loop then holds and exits. Sensor
frames older than the newest (reordered by the network) are counted as ``stale`` and
dropped.
"""

from __future__ import annotations

import socket
import time
from collections import Counter
from typing import Any

import numpy as np

from jaxenvs.deploy import wire
from jaxenvs.deploy.simrobot import parse_address
from jaxenvs.robots.interface import LinkError, RobotSpec, SensorFrame


class TcpRobot:
    """A robot at ``tcp://HOST:PORT`` (see the module docstring).

    Attributes:
      counts: bad or late messages received, by reason.
      robot_counts: the robot's own counts of bad messages (from its ``bye``).
      privileged: the robot also sends ground-truth ``state`` messages.
    """

    def __init__(self, address: str, timeout: float = 10.0) -> None:
        self.address = address
        self.host, self.port = parse_address(address)
        self.timeout = timeout
        self.sock: socket.socket | None = None
        self.reader = wire.FrameReader()
        self.counts: Counter[str] = Counter()
        self.robot_counts: dict[str, int] = {}
        self.spec: RobotSpec | None = None
        self.privileged = False
        self._latest: SensorFrame | None = None
        self._truth: tuple[int, dict[str, np.ndarray]] | None = None
        self._new_truths: list[tuple[int, dict[str, np.ndarray]]] = []
        self._sizes: dict[str, int] = {}
        self._dims: tuple[int, int, int] = (0, 0, 0)
        self._ended = ""

    # ------------------------------------------------------------------ the protocol
    def connect(self) -> RobotSpec:
        """Connect, read the robot's hello (within ``timeout`` s) and return its spec."""
        try:
            sock = socket.create_connection((self.host, self.port), timeout=self.timeout)
        except OSError as err:
            raise LinkError(f"cannot connect to {self.address}: {err.strerror or err}") from None
        sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        self.sock = sock
        hello = self._first_message()
        if hello.get("type") != "hello" or hello.get("version") != wire.VERSION:
            raise LinkError(f"{self.address} did not say hello (version {wire.VERSION})")
        try:
            self.spec = RobotSpec.from_json(hello)
        except ValueError as err:
            raise LinkError(f"{self.address}: {err}") from None
        self.privileged = bool(hello.get("privileged", False))
        self._sizes = self.spec.sizes()
        sock.setblocking(False)
        return self.spec

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

    def hold(self, reason: str) -> None:
        """Best effort: a hold message (the robot also holds on its own watchdog)."""
        try:
            self._send({"type": "hold", "seq": 0, "reason": reason[:200]})
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

    def _first_message(self) -> dict[str, Any]:
        assert self.sock is not None
        end = time.monotonic() + self.timeout
        while time.monotonic() < end:
            try:
                data = self.sock.recv(1 << 16)
            except TimeoutError:
                break
            except OSError as err:
                raise LinkError(f"link lost before hello ({err.strerror or err})") from None
            if not data:
                raise LinkError(f"{self.address} closed the link before its hello")
            try:
                messages = self.reader.feed(data)
            except wire.FramingError as err:
                raise LinkError(f"malformed message from the robot: {err}") from None
            if messages:
                return messages[0]
        raise LinkError(f"no hello from {self.address} within {self.timeout:g} s")

    def _poll(self, block: float = 0.0) -> None:
        """Read whatever has arrived (waiting up to ``block`` s for the first bytes)."""
        assert self.sock is not None
        self.sock.settimeout(block if block > 0 else 0.0)
        while True:
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
            try:
                messages = self.reader.feed(data)
            except wire.FramingError as err:
                raise LinkError(f"malformed message from the robot: {err}") from None
            if self.reader.counts["malformed"]:
                raise LinkError("malformed message from the robot (not a JSON object)")
            for msg in messages:
                self._handle(msg, time.monotonic())
            self.sock.settimeout(0.0)

    def _handle(self, msg: dict[str, Any], now: float) -> None:
        kind = msg["type"]
        try:
            if kind == "sensors":
                last = -1 if self._latest is None else self._latest.seq
                seq, stamp, acked, readings = wire.parse_sensors(msg, self._sizes, last)
                self._latest = SensorFrame(seq, stamp, readings, now, acked)
            elif kind == "state":
                if self._dims == (0, 0, 0):
                    return
                last = -1 if self._truth is None else self._truth[0]
                self._truth = wire.parse_state(msg, *self._dims, last)
                self._new_truths.append(self._truth)
            elif kind == "bye":
                counts = msg.get("counts")
                self.robot_counts = dict(counts) if isinstance(counts, dict) else {}
                self._ended = str(msg.get("reason", ""))[:200] or "bye"
            else:
                raise wire.BadMessage("malformed", f"unexpected message type {kind!r}")
        except wire.BadMessage as bad:
            self.counts[bad.reason] += 1
            if bad.reason != "stale":
                raise LinkError(f"malformed message from the robot ({bad})") from None

    @property
    def ended(self) -> str:
        """The robot's reason, once it said bye ('' before)."""
        return self._ended


__all__ = ["TcpRobot"]
