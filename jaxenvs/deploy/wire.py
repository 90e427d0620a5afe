"""The messages between a robot and the deploy loop, and their framing on a byte stream.

Framing: each message is a 4-byte big-endian unsigned length ``N`` (1 <= N <=
:data:`MAX_FRAME`) followed by ``N`` bytes of UTF-8 JSON: one object with a ``"type"``.
A frame whose length is out of range cannot be skipped (the stream has lost its framing):
it ends the link. A well-framed message that is not valid (bad JSON, nested deeper than
:data:`MAX_DEPTH`, missing field, wrong size, a number that does not fit a float, an old
sequence number) is counted under its reason and dropped: nothing a peer sends raises
anything here but :class:`BadMessage` and :class:`FramingError`. An integer of more than
:data:`INT_DIGITS` digits is read as a float (so it is no sequence number, and a reading
beyond a float's range is not finite).

==========  =========  ==================================================================
type        from       fields
==========  =========  ==================================================================
challenge   robot      KEYED LINK ONLY, first: ``version``, ``nonce`` (:mod:`.auth`)
auth        loop       KEYED LINK ONLY, the answer: ``nonce``, ``mac``
hello       robot      ``version``, :meth:`RobotSpec.to_json` fields, ``privileged``
                       (bool: it also sends ``state``); on a keyed link ``mac``
sensors     robot      ``seq`` (int, +1 per frame), ``stamp`` (robot clock, s), ``acked``
                       (the last command seq applied, -1 before any), ``readings``
                       (sensor name -> list of ``size`` numbers)
state       robot      PRIVILEGED (a simulator only): ``seq`` (the sensors frame's),
                       ``stamp``, ``qpos``, ``qvel``, ``mocap_pos`` (lists)
command     loop       ``seq`` (int, increasing), ``action`` (one number in [-1, 1] per
                       actuator, the robot's command map applies)
hold        loop       ``seq`` (above every command's), ``reason``: safe stop (action 0)
bye         either     ``reason``, and from the robot ``counts`` (bad messages by reason)
==========  =========  ==================================================================

Everything here is the standard library and numpy.
"""

from __future__ import annotations

import json
import math
import struct
from collections import Counter
from collections.abc import Mapping
from typing import Any

import numpy as np

#: the message format's version (the hello's ``version``)
VERSION = 1
#: the largest frame either side accepts (bytes of JSON)
MAX_FRAME = 1 << 20
#: the deepest nesting of arrays and objects a message may have (the messages need 3)
MAX_DEPTH = 16
#: integers of more digits are read as floats (an int64 has 19)
INT_DIGITS = 18
_HEADER = struct.Struct(">I")
#: reasons a message is counted as bad
REASONS = ("malformed", "wrong_size", "non_finite", "stale", "out_of_range")


class BadMessage(ValueError):
    """A message that is dropped and counted; ``reason`` is one of :data:`REASONS`."""

    def __init__(self, reason: str, detail: str) -> None:
        super().__init__(f"{reason}: {detail}")
        self.reason = reason


class FramingError(ValueError):
    """The byte stream lost its framing (a length out of range): the link must end."""


def encode(message: Mapping[str, Any]) -> bytes:
    """One framed message (non-finite floats are refused: JSON has none)."""
    body = json.dumps(message, separators=(",", ":"), allow_nan=False).encode()
    if len(body) > MAX_FRAME:
        raise ValueError(f"message of {len(body)} bytes exceeds {MAX_FRAME}")
    return _HEADER.pack(len(body)) + body


def _int(text: str) -> int | float:
    """A JSON integer: an ``int`` up to :data:`INT_DIGITS` digits, a float beyond (never
    Python's integer-string limit, never an integer no float can hold)."""
    return int(text) if len(text.lstrip("-")) <= INT_DIGITS else float(text)


_DECODER = json.JSONDecoder(parse_int=_int)


def _too_deep(obj: Any) -> bool:
    """Whether ``obj`` nests lists and dicts deeper than :data:`MAX_DEPTH` (no recursion)."""
    stack = [(obj, 1)]
    while stack:
        item, depth = stack.pop()
        for child in item.values() if isinstance(item, dict) else item:
            if isinstance(child, (dict, list)):
                if depth + 1 > MAX_DEPTH:
                    return True
                stack.append((child, depth + 1))
    return False


def decode(body: bytes) -> dict[str, Any]:
    """The message of one frame's body; :class:`BadMessage` (``malformed``) when it is not
    UTF-8 JSON, nests deeper than :data:`MAX_DEPTH` or is not an object with a string
    ``type``."""
    try:
        obj = _DECODER.decode(body.decode())
    except UnicodeDecodeError:
        raise BadMessage("malformed", "not UTF-8") from None
    except RecursionError:
        raise BadMessage("malformed", f"nested deeper than {MAX_DEPTH}") from None
    except ValueError as err:  # JSONDecodeError, and any number the parser refuses
        raise BadMessage("malformed", f"not JSON ({str(err)[:80]})") from None
    if not isinstance(obj, dict) or not isinstance(obj.get("type"), str):
        raise BadMessage("malformed", "not a JSON object with a string type")
    # at most MAX_DEPTH brackets (strings' included) cannot nest deeper: most frames
    if body.count(b"[") + body.count(b"{") > MAX_DEPTH and _too_deep(obj):
        raise BadMessage("malformed", f"nested deeper than {MAX_DEPTH}")
    return obj


class FrameReader:
    """Incremental decoder: :meth:`feed` bytes as they arrive, get whole messages back.

    Frames that :func:`decode` refuses are counted in :attr:`counts` under
    ``"malformed"`` (the latest one's reason in :attr:`last_bad`); a length out of range
    raises :class:`FramingError`.
    """

    def __init__(self, counts: Counter[str] | None = None) -> None:
        self._buf = bytearray()
        #: bad messages by reason (``counts``, when given, is counted into)
        self.counts: Counter[str] = Counter() if counts is None else counts
        #: why the latest malformed frame was refused ('' before any)
        self.last_bad = ""

    def feed(self, data: bytes) -> list[dict[str, Any]]:
        """Decode every whole frame in the bytes received so far."""
        self._buf += data
        out = []
        while len(self._buf) >= _HEADER.size:
            (n,) = _HEADER.unpack_from(self._buf)
            if not 1 <= n <= MAX_FRAME:
                raise FramingError(f"frame length {n} is out of range (1..{MAX_FRAME})")
            if len(self._buf) < _HEADER.size + n:
                break
            body = bytes(self._buf[_HEADER.size : _HEADER.size + n])
            del self._buf[: _HEADER.size + n]
            try:
                out.append(decode(body))
            except BadMessage as bad:
                self.counts[bad.reason] += 1
                self.last_bad = str(bad)
        return out


def _seq(obj: Mapping[str, Any], last: int) -> int:
    seq = obj.get("seq")
    if not isinstance(seq, int) or isinstance(seq, bool):
        raise BadMessage("malformed", "seq must be an integer")
    if seq <= last:
        raise BadMessage("stale", f"seq {seq} after {last}")
    return seq


def _numbers(value: Any, size: int, what: str) -> np.ndarray:
    if not isinstance(value, list) or not all(
        isinstance(v, (int, float)) and not isinstance(v, bool) for v in value
    ):
        raise BadMessage("malformed", f"{what} must be a list of numbers")
    if len(value) != size:
        raise BadMessage("wrong_size", f"{what} has {len(value)} numbers, expected {size}")
    try:
        arr = np.asarray(value, np.float64)
    except OverflowError:  # an integer no float holds (one made in Python, not decoded)
        raise BadMessage("non_finite", f"{what} does not fit a float") from None
    if not np.all(np.isfinite(arr)):
        raise BadMessage("non_finite", f"{what} is not finite")
    return arr


def _number(value: Any) -> bool:
    """A finite JSON number (not a bool)."""
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        return False
    try:
        return math.isfinite(value)
    except OverflowError:
        return False


def command(seq: int, action: np.ndarray) -> dict[str, Any]:
    """The command message of ``action`` (one number in [-1, 1] per actuator)."""
    return {"type": "command", "seq": int(seq), "action": [float(a) for a in action]}


def parse_command(obj: Mapping[str, Any], actuators: int, last_seq: int) -> tuple[int, np.ndarray]:
    """``(seq, action)`` of a command message; :class:`BadMessage` when it is malformed,
    of the wrong size, not finite, outside [-1, 1] or older than ``last_seq``."""
    action = _numbers(obj.get("action"), actuators, "action")
    if np.any(np.abs(action) > 1.0):
        raise BadMessage("out_of_range", "action outside [-1, 1]")
    return _seq(obj, last_seq), action


def sensors(seq: int, stamp: float, acked: int, readings: Mapping[str, Any]) -> dict[str, Any]:
    """The sensors message of ``readings`` (sensor name -> array)."""
    return {
        "type": "sensors",
        "seq": int(seq),
        "stamp": float(stamp),
        "acked": int(acked),
        "readings": {k: [float(x) for x in np.ravel(v)] for k, v in readings.items()},
    }


def parse_sensors(
    obj: Mapping[str, Any], sizes: Mapping[str, int], last_seq: int
) -> tuple[int, float, int, dict[str, np.ndarray]]:
    """``(seq, stamp, acked, readings)`` of a sensors message with every sensor of
    ``sizes`` (name -> size); :class:`BadMessage` otherwise."""
    readings = obj.get("readings")
    stamp: Any = obj.get("stamp")
    acked = obj.get("acked", -1)
    if not isinstance(readings, dict) or not _number(stamp):
        raise BadMessage("malformed", "sensors needs readings (an object) and a finite stamp")
    if not isinstance(acked, int) or isinstance(acked, bool) or acked < -1:
        raise BadMessage("malformed", "acked must be an integer >= -1")
    if set(readings) != set(sizes):
        raise BadMessage("wrong_size", f"readings of {sorted(readings)}, expected {sorted(sizes)}")
    out = {name: _numbers(readings[name], size, name) for name, size in sizes.items()}
    return _seq(obj, last_seq), float(stamp), acked, out


def state(seq: int, stamp: float, qpos: Any, qvel: Any, mocap_pos: Any) -> dict[str, Any]:
    """The privileged ground-truth message of a simulated robot."""
    return {
        "type": "state",
        "seq": int(seq),
        "stamp": float(stamp),
        "qpos": np.asarray(qpos, np.float64).tolist(),
        "qvel": np.asarray(qvel, np.float64).tolist(),
        "mocap_pos": np.asarray(mocap_pos, np.float64).tolist(),
    }


def parse_state(
    obj: Mapping[str, Any], nq: int, nv: int, nmocap: int, last_seq: int
) -> tuple[int, dict[str, np.ndarray]]:
    """``(seq, {"qpos", "qvel", "mocap_pos"})`` of a state message; :class:`BadMessage`
    otherwise."""
    mocap = obj.get("mocap_pos")
    if not isinstance(mocap, list) or len(mocap) != nmocap:
        raise BadMessage("wrong_size", f"mocap_pos must hold {nmocap} positions")
    truth = {
        "qpos": _numbers(obj.get("qpos"), nq, "qpos"),
        "qvel": _numbers(obj.get("qvel"), nv, "qvel"),
        "mocap_pos": np.asarray([_numbers(p, 3, "mocap_pos") for p in mocap]).reshape(nmocap, 3),
    }
    return _seq(obj, last_seq), truth


__all__ = [
    "MAX_FRAME",
    "REASONS",
    "VERSION",
    "INT_DIGITS",
    "MAX_DEPTH",
    "BadMessage",
    "FrameReader",
    "FramingError",
    "command",
    "decode",
    "encode",
    "parse_command",
    "parse_sensors",
    "parse_state",
    "sensors",
    "state",
]
