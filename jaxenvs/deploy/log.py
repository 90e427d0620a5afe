"""The deploy loop's log: an MCAP file of JSON messages (``pip install mcap``), the
format robotics viewers (Foxglove, the ``mcap`` CLI, ROS 2's rosbag2 MCAP storage)
read. Each message's log time is the loop's wall clock in nanoseconds.

=====================  ===============================================================
topic                  message (JSON)
=====================  ===============================================================
``/robot/hello``       the robot's hello (:class:`~jaxenvs.robots.interface.RobotSpec`)
``/robot/sensors``     each sensor frame the loop acted on: ``seq``, ``stamp``, ``acked``,
                       ``readings``
``/robot/state``       PRIVILEGED ground truth of a simulated robot: ``seq``, ``qpos``,
                       ``qvel``, ``mocap_pos``
``/deploy/command``    each step: ``step``, ``seq``, ``tick`` and ``sent`` (s since the
                       start), ``obs``, ``action`` (the policy's), ``command`` (the
                       actuator action sent), ``task`` (the task's own state)
``/deploy/event``      ``{"event": "hold" | "end", "reason": ...}``
``/deploy/summary``    the run's summary (:mod:`jaxenvs.deploy.loop`)
=====================  ===============================================================

Chunks are small (:data:`CHUNK`) and the file is finished on every exit the loop sees,
so a run that fails keeps a complete, readable log. :func:`read_log` reads a file
sequentially (also one whose writer was killed before finishing it).
"""

from __future__ import annotations

import json
import time
from pathlib import Path
from typing import IO, Any

import numpy as np

#: bytes of messages per MCAP chunk (a killed writer loses at most this much)
CHUNK = 16 << 10
TOPICS = (
    "/robot/hello",
    "/robot/sensors",
    "/robot/state",
    "/deploy/command",
    "/deploy/event",
    "/deploy/summary",
)


def _jsonable(value: Any) -> Any:
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, (np.floating, np.integer, np.bool_)):
        return value.item()
    if isinstance(value, dict):
        return {str(k): _jsonable(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_jsonable(v) for v in value]
    return value


class LogWriter:
    """Writes the topics of :data:`TOPICS` to an MCAP file; :meth:`close` finishes it."""

    def __init__(self, path: str | Path) -> None:
        try:
            from mcap.writer import CompressionType, Writer
        except ImportError:
            raise ValueError(
                "--log needs the mcap package: pip install 'jaxenvs[export]'"
            ) from None
        self.path = Path(path)
        self._file: IO[bytes] | None = open(self.path, "wb")  # noqa: SIM115 (closed in close())
        self._writer = Writer(self._file, chunk_size=CHUNK, compression=CompressionType.NONE)
        self._writer.start(profile="", library="jaxenvs")
        schema = self._writer.register_schema(
            name="json", encoding="jsonschema", data=json.dumps({"type": "object"}).encode()
        )
        self._channels = {t: self._writer.register_channel(t, "json", schema) for t in TOPICS}
        self._seq = 0

    def write(self, topic: str, message: dict[str, Any], stamp_ns: int | None = None) -> None:
        """Append one message (numpy values become lists)."""
        if self._file is None:
            return
        now = time.time_ns() if stamp_ns is None else stamp_ns
        data = json.dumps(_jsonable(message), allow_nan=True).encode()
        self._seq += 1
        self._writer.add_message(self._channels[topic], now, data, now, self._seq)

    def close(self) -> None:
        """Finish the file (summary and index) and close it; safe to call twice."""
        if self._file is None:
            return
        try:
            self._writer.finish()
        finally:
            self._file.close()
            self._file = None


def read_log(path: str | Path) -> dict[str, list[dict[str, Any]]]:
    """Every message of a log by topic, in log order (``ValueError`` when unreadable)."""
    from mcap.exceptions import McapError
    from mcap.reader import NonSeekingReader

    out: dict[str, list[dict[str, Any]]] = {t: [] for t in TOPICS}
    path = Path(path)
    if not path.is_file():
        raise ValueError(f"no log file at {path}")
    with open(path, "rb") as f:
        try:
            # in file order: a log is written in time order, and an unfinished file's
            # messages are yielded up to its last whole chunk
            for _, channel, message in NonSeekingReader(f).iter_messages(log_time_order=False):
                out.setdefault(channel.topic, []).append(json.loads(message.data))
        except (McapError, json.JSONDecodeError, EOFError) as err:
            if not any(out.values()):
                raise ValueError(
                    f"{path}: not a readable MCAP log ({type(err).__name__} {err})"
                ) from None
    return out


def poses(messages: dict[str, list[dict[str, Any]]], model: Any, encoders: dict[str, int]) -> Any:
    """The logged run's poses ``(qpos (T, nq), mocap_pos (T, nmocap, 3) or None)``: the
    privileged ground truth when the robot sent it, else the joint encoders' readings
    (``encoders``: sensor name -> qpos address) over the model's default pose."""
    states = messages["/robot/state"]
    if states:
        qpos = np.asarray([s["qpos"] for s in states], np.float64)
        mocap = np.asarray([s["mocap_pos"] for s in states], np.float64).reshape(
            len(states), model.nmocap, 3
        )
        return qpos, mocap
    frames = messages["/robot/sensors"]
    if not frames:
        raise ValueError("the log holds no sensor readings and no ground truth")
    qpos = np.tile(np.asarray(model.qpos0, np.float64), (len(frames), 1))
    for name, adr in encoders.items():
        qpos[:, adr] = [f["readings"][name][0] for f in frames]
    return qpos, None


__all__ = ["CHUNK", "TOPICS", "LogWriter", "poses", "read_log"]
