"""A robot's side of the jaxenvs link, in one file of Python's standard library: the pattern
to port to a robot's firmware or a ROS 2 bridge (docs/robot_interface.md, Option 1).

Put your driver in :class:`Robot` (``read_sensors``, ``apply``, ``hold``) and your robot's
spec in ``--spec`` (``jaxenvs.robots.interface.spec_of(env, env_id).to_json()`` as a JSON
file), make a key and run it::

    (umask 077; python -c 'import secrets; print(secrets.token_hex(32))' > robot.key)
    python robot_firmware.py --spec spec.json --listen 0.0.0.0:5555 --key-file robot.key
    jaxenvs deploy POLICY --env ID --robot tcp://ROBOT:5555 --key-file robot.key --seconds 20

One loop at a time. With a key (needed beyond this computer) a client must answer the
challenge before it gets the hello or any sensor frame. Only valid commands are applied
(the right number of finite actions in [-1, 1], a ``seq`` above the last one); everything
else is counted and dropped, never fatal. The robot holds on a ``hold``, a ``bye``, a lost
link, and after ``WATCHDOG`` periods without a valid command.
"""

from __future__ import annotations

import argparse
import hashlib
import hmac
import json
import math
import os
import secrets
import socket
import stat
import struct
import time
from collections import Counter
from typing import Any

MAX_FRAME = 1 << 20  # the largest frame either side accepts
WATCHDOG = 5  # control periods without a valid command before the robot holds
AUTH_TIMEOUT = 5.0  # seconds a client has to answer the challenge


class Robot:
    """Your hardware. This stand-in reads zeros and remembers what it was told."""

    def __init__(self, spec: dict[str, Any]) -> None:
        self.spec = spec
        self.applied: list[list[float]] = []
        self.held = True

    def read_sensors(self) -> dict[str, list[float]]:
        return {s["name"]: [0.0] * s["size"] for s in self.spec["sensors"]}

    def apply(self, action: list[float]) -> None:  # action in [-1, 1] per actuator
        self.applied.append(action)
        self.held = False

    def hold(self) -> None:  # safe stop: action 0 (zero force, the neutral pose)
        self.held = True


def send(conn: socket.socket, message: dict[str, Any]) -> None:
    body = json.dumps(message).encode()
    conn.sendall(struct.pack(">I", len(body)) + body)


def decode(body: bytes) -> dict[str, Any] | None:
    """A message, or None for anything that is not a JSON object with a string type
    (too deep, an integer longer than 18 digits read as a float, not UTF-8, ...)."""
    try:
        msg = json.loads(body, parse_int=lambda s: int(s) if len(s) <= 18 else float(s))
    except (ValueError, RecursionError):
        return None
    return msg if isinstance(msg, dict) and isinstance(msg.get("type"), str) else None


def frames(buf: bytearray) -> list[bytes] | None:
    """Cut the whole frames off ``buf``; None when a length is out of range (close)."""
    out = []
    while len(buf) >= 4:
        (n,) = struct.unpack(">I", buf[:4])
        if not 1 <= n <= MAX_FRAME:
            return None
        if len(buf) < 4 + n:
            break
        out.append(bytes(buf[4 : 4 + n]))
        del buf[: 4 + n]
    return out


def mac(key: bytes, role: str, first: str, second: str) -> str:
    text = f"jaxenvs-link-1 {role} {first} {second}".encode()
    return hmac.new(key, text, hashlib.sha256).hexdigest()


def handshake(conn: socket.socket, key: bytes) -> str | None:
    """Challenge the client; the hello's ``mac`` when it proved the key, else None."""
    ours = secrets.token_hex(32)
    send(conn, {"type": "challenge", "version": 1, "nonce": ours})
    conn.settimeout(AUTH_TIMEOUT)
    buf, end = bytearray(), time.monotonic() + AUTH_TIMEOUT
    try:
        while (got := frames(buf)) == [] and time.monotonic() < end:
            data = conn.recv(65536)
            if not data:
                return None
            buf += data
    except OSError:
        return None
    msg = decode(got[0]) if got else None
    theirs = msg.get("nonce") if msg else None
    if not (msg and msg["type"] == "auth" and isinstance(theirs, str) and len(theirs) >= 32):
        return None
    answer = msg.get("mac")
    if not isinstance(answer, str) or not hmac.compare_digest(
        mac(key, "loop", ours, theirs).encode(), answer.encode()
    ):
        return None
    return mac(key, "robot", theirs, ours)


def valid_command(msg: dict[str, Any], actuators: int, last: int) -> str | None:
    """Why a command is dropped (a reason of the wire's counts), or None to apply it."""
    seq, action = msg.get("seq"), msg.get("action")
    if type(seq) is not int or not isinstance(action, list):
        return "malformed"
    if not all(type(a) in (int, float) for a in action):
        return "malformed"
    if len(action) != actuators:
        return "wrong_size"
    if not all(math.isfinite(a) for a in action):
        return "non_finite"
    if not all(-1.0 <= a <= 1.0 for a in action):
        return "out_of_range"
    return "stale" if seq <= last else None


def serve_client(conn: socket.socket, robot: Robot, key: bytes | None) -> Counter[str]:
    """Serve one loop until it leaves; the messages dropped, by reason."""
    spec, counts = robot.spec, Counter[str]()
    conn.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
    proof = handshake(conn, key) if key is not None else None
    if key is not None and proof is None:
        send(conn, {"type": "bye", "reason": "authentication failed"})
        return Counter(refused=1)
    hello = {"type": "hello", "version": 1, "privileged": False, **spec}
    send(conn, hello if proof is None else {**hello, "mac": proof})
    conn.setblocking(False)
    dt, n = spec["control_dt"], len(spec["actuators"])
    buf, seq, last, since, t0 = bytearray(), 0, -1, 0, time.monotonic()
    try:
        while True:
            send(conn, {"type": "sensors", "seq": seq, "stamp": time.monotonic() - t0,
                        "acked": last, "readings": robot.read_sensors()})  # fmt: skip
            seq, since = seq + 1, since + 1
            try:
                data = conn.recv(65536)
                if not data:
                    break  # the loop left
                buf += data
            except BlockingIOError:
                pass
            got = frames(buf)
            if got is None:
                break  # the stream lost its framing
            for body in got:
                msg = decode(body)
                kind = msg["type"] if msg else None
                why = valid_command(msg, n, last) if msg and kind == "command" else None
                if msg is None or kind not in ("command", "hold", "bye") or why:
                    counts[why or "malformed"] += 1
                elif kind == "command":
                    robot.apply(msg["action"])
                    last, since = msg["seq"], 0
                elif kind == "hold":
                    robot.hold()
                else:
                    send(conn, {"type": "bye", "reason": "bye", "counts": dict(counts)})
                    return counts
            if since > WATCHDOG and not robot.held:
                robot.hold()
            time.sleep(max(0.0, dt - (time.monotonic() - t0) % dt))
    except OSError:
        pass  # the link is gone
    finally:
        robot.hold()
    return counts


def read_key(path: str) -> bytes:
    if os.stat(path).st_mode & (stat.S_IROTH | stat.S_IWOTH):
        raise SystemExit(f"{path} is readable by every user: chmod 600 {path}")
    with open(path, "rb") as f:
        key = f.read().strip()
    if len(key) < 16:
        raise SystemExit(f"the key in {path} is shorter than 16 bytes")
    return key


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--spec", required=True, help="the robot's spec (JSON)")
    parser.add_argument("--listen", default="127.0.0.1:5555", help="HOST:PORT")
    parser.add_argument("--key-file", help="serve only a loop that proves this key")
    args = parser.parse_args()
    host, _, port = args.listen.rpartition(":")
    key = read_key(args.key_file) if args.key_file else None
    if key is None and host not in ("127.0.0.1", "localhost", "::1"):
        raise SystemExit("beyond this computer, give --key-file")
    with open(args.spec) as f:
        robot = Robot(json.load(f))
    with socket.create_server((host, int(port))) as server:
        while True:
            conn, peer = server.accept()
            with conn:
                print(peer[0], dict(serve_client(conn, robot, key)), flush=True)


if __name__ == "__main__":
    main()
