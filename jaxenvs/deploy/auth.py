"""The robot link's key: a shared secret in a file, and the challenge-response that proves
a peer holds it (HMAC-SHA256 over fresh nonces, Python's ``hmac`` and ``secrets``; any
firmware with a SHA-256 can do the same).

On a keyed link the robot speaks first with a challenge instead of its hello::

    robot -> loop   {"type": "challenge", "version": 1, "nonce": RN}
    loop -> robot   {"type": "auth", "nonce": LN, "mac": proof(key, "loop", RN, LN)}
    robot -> loop   {"type": "hello", ..., "mac": proof(key, "robot", LN, RN)}

``RN`` and ``LN`` are fresh random nonces (:data:`NONCE_BYTES` bytes, as lowercase hex),
one per connection from each side, so a recorded answer is worth nothing on the next
connection. :func:`proof` is the lowercase hex HMAC-SHA256, keyed with the key file's
bytes, of the ASCII text ``"jaxenvs-link-1 ROLE FIRST SECOND"``. A robot that receives
anything but a right ``auth`` answers ``{"type": "bye", "reason": "authentication
failed"}`` and closes, having sent no sensor frame and applied no command; the loop checks
the hello's ``mac`` in turn, so it never drives a robot that does not hold the key.

The handshake authenticates both ends once per connection; it does not encrypt the link
nor sign each message (use a VPN or an SSH tunnel across a network you do not trust).
"""

from __future__ import annotations

import hashlib
import hmac
import ipaddress
import secrets
import socket
import stat
from pathlib import Path
from typing import TypeGuard

#: bytes of each side's nonce (sent as twice as many hex digits)
NONCE_BYTES = 32
#: the shortest key accepted (bytes, after surrounding whitespace is stripped)
KEY_MIN = 16
#: the longest key file read (bytes)
KEY_MAX = 4096
#: how long a robot waits for a client's answer to its challenge (s)
AUTH_TIMEOUT = 5.0
#: what the robot's bye says when a client failed the handshake
REFUSED = "authentication failed"
_LABEL = "jaxenvs-link-1"
#: how to make a key file that passes :func:`read_key`
MAKE_KEY = "(umask 077; python -c 'import secrets; print(secrets.token_hex(32))' > robot.key)"


def read_key(path: str | Path) -> bytes:
    """The key in ``path`` (its bytes, surrounding whitespace stripped); ``ValueError``
    naming the problem when it is missing, readable or writable by every user, shorter
    than :data:`KEY_MIN` bytes or longer than :data:`KEY_MAX`."""
    path = Path(path)
    try:
        mode = path.stat().st_mode
    except OSError as err:
        raise ValueError(f"cannot read the key file {path}: {err.strerror or err}") from None
    if not stat.S_ISREG(mode):
        raise ValueError(f"the key file {path} is not a regular file")
    if mode & (stat.S_IROTH | stat.S_IWOTH):
        raise ValueError(
            f"the key file {path} is readable or writable by every user "
            f"(mode {stat.S_IMODE(mode):04o}): chmod 600 {path}"
        )
    try:
        with open(path, "rb") as f:
            key = f.read(KEY_MAX + 1)
    except OSError as err:
        raise ValueError(f"cannot read the key file {path}: {err.strerror or err}") from None
    if len(key) > KEY_MAX:
        raise ValueError(f"the key file {path} holds more than {KEY_MAX} bytes")
    key = key.strip()
    if len(key) < KEY_MIN:
        raise ValueError(
            f"the key in {path} is shorter than {KEY_MIN} bytes; make one with: {MAKE_KEY}"
        )
    return key


def nonce() -> str:
    """A fresh random nonce: :data:`NONCE_BYTES` bytes as lowercase hex."""
    return secrets.token_hex(NONCE_BYTES)


def proof(key: bytes, role: str, first: str, second: str) -> str:
    """The lowercase hex HMAC-SHA256, keyed with ``key``, of
    ``"jaxenvs-link-1 ROLE FIRST SECOND"`` (``role``: ``loop`` or ``robot``)."""
    text = f"{_LABEL} {role} {first} {second}".encode()
    return hmac.new(key, text, hashlib.sha256).hexdigest()


def verify(key: bytes, role: str, first: str, second: str, mac: object) -> bool:
    """Whether ``mac`` is :func:`proof` of the same arguments (compared in constant time;
    anything but a string is not)."""
    if not isinstance(mac, str) or not isinstance(first, str) or not isinstance(second, str):
        return False
    return hmac.compare_digest(proof(key, role, first, second).encode(), mac.encode())


def valid_nonce(value: object) -> TypeGuard[str]:
    """Whether ``value`` is a nonce as :func:`nonce` makes them (hex, at least 16 bytes)."""
    if not isinstance(value, str) or not 32 <= len(value) <= 4 * NONCE_BYTES:
        return False
    return all(c in "0123456789abcdef" for c in value)


def is_loopback(host: str) -> bool:
    """Whether ``host`` (an address or a name) means this computer only: every address it
    resolves to is a loopback address (``0.0.0.0`` and ``::``, every interface, are
    not)."""
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        pass
    try:
        infos = socket.getaddrinfo(host, None)
    except (OSError, UnicodeError):
        return False
    addresses = {info[4][0] for info in infos}
    return bool(addresses) and all(
        ipaddress.ip_address(str(a).split("%")[0]).is_loopback for a in addresses
    )


__all__ = [
    "AUTH_TIMEOUT",
    "KEY_MAX",
    "KEY_MIN",
    "NONCE_BYTES",
    "REFUSED",
    "is_loopback",
    "nonce",
    "proof",
    "read_key",
    "valid_nonce",
    "verify",
]
