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
sequentially (also one whose writer was killed before finishing it, or that was cut at
any byte).

A write that fails (a full disk) raises :class:`LogError` once: the file is cut back to
its last whole record (each record goes to the file in one unbuffered write), so it
stays readable up to there, and the writer writes nothing more.
"""

from __future__ import annotations

import json
import os
import time
from pathlib import Path
from typing import Any

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


class LogError(RuntimeError):
    """The log could not be written (the message is one line naming the file and why)."""


def _write(fd: int, data: memoryview) -> int:
    """``os.write`` (the one place the log's bytes leave the process; tests replace it)."""
    return os.write(fd, data)


class _Sink:
    """The log file, unbuffered, as the MCAP writer's stream: a write is whole, or the
    file is cut back to where it began and ``OSError`` raised."""

    def __init__(self, path: Path) -> None:
        self.fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o644)
        self.pos = 0

    def write(self, data: bytes) -> int:
        view, done = memoryview(data), 0
        try:
            while done < len(view):
                done += _write(self.fd, view[done:])
        except OSError:
            try:
                os.ftruncate(self.fd, self.pos)
            except OSError:
                pass
            raise
        self.pos += done
        return done

    def tell(self) -> int:
        return self.pos

    def flush(self) -> None:
        pass

    def close(self) -> None:
        os.close(self.fd)


class LogWriter:
    """Writes the topics of :data:`TOPICS` to an MCAP file; :meth:`close` finishes it.
    :meth:`write` and :meth:`close` raise :class:`LogError` when the file cannot be
    written (once; the writer then drops what it is given, and the file holds every whole
    record written before)."""

    def __init__(self, path: str | Path) -> None:
        try:
            from mcap.writer import CompressionType, Writer
        except ImportError:
            raise ValueError(
                "--log needs the mcap package: pip install 'jaxenvs[export]'"
            ) from None
        self.path = Path(path)
        self._sink: _Sink | None = _Sink(self.path)
        self._writer = Writer(  # a stream is what it writes to, tells and flushes
            self._sink,  # type: ignore[arg-type]
            chunk_size=CHUNK,
            compression=CompressionType.NONE,
        )
        #: why the log stopped ('' while it is written)
        self.failed = ""
        try:
            self._writer.start(profile="", library="jaxenvs")
            schema = self._writer.register_schema(
                name="json", encoding="jsonschema", data=json.dumps({"type": "object"}).encode()
            )
            self._channels = {t: self._writer.register_channel(t, "json", schema) for t in TOPICS}
        except OSError as err:
            self._sink.close()
            self._sink = None
            raise ValueError(f"cannot write the log {self.path}: {err.strerror or err}") from None
        self._seq = 0

    def _fail(self, err: OSError) -> LogError:
        """Stop writing (the file keeps its whole records) and say why."""
        self.failed = f"cannot write the log {self.path}: {err.strerror or err}"
        if self._sink is not None:
            self._sink.close()
            self._sink = None
        return LogError(self.failed)

    def write(self, topic: str, message: dict[str, Any], stamp_ns: int | None = None) -> None:
        """Append one message (numpy values become lists)."""
        if self._sink is None:
            return
        now = time.time_ns() if stamp_ns is None else stamp_ns
        data = json.dumps(_jsonable(message), allow_nan=True).encode()
        self._seq += 1
        try:
            self._writer.add_message(self._channels[topic], now, data, now, self._seq)
        except OSError as err:
            raise self._fail(err) from None

    def close(self) -> None:
        """Finish the file (summary and index) and close it; safe to call twice."""
        if self._sink is None:
            return
        try:
            self._writer.finish()
        except OSError as err:
            raise self._fail(err) from None
        self._sink.close()
        self._sink = None


def read_log(path: str | Path) -> dict[str, list[dict[str, Any]]]:
    """Every message of a log by topic, in log order: of a damaged file (cut at any byte,
    bytes changed), those before the damage; ``ValueError`` when not one is readable."""
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
                obj = json.loads(message.data)
                if not isinstance(obj, dict):
                    raise ValueError("a message that is not a JSON object")
                out.setdefault(channel.topic, []).append(obj)
        except Exception as err:  # noqa: BLE001 (damaged bytes fail the reader in many ways)
            # a file cut short (or damaged) is read up to its last whole record
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
    try:
        if states:
            qpos = np.asarray([s["qpos"] for s in states], np.float64).reshape(len(states), -1)
            mocap = np.asarray([s["mocap_pos"] for s in states], np.float64).reshape(
                len(states), model.nmocap, 3
            )
            if qpos.shape[1] != model.nq:
                raise ValueError(f"qpos of {qpos.shape[1]} values, the model has {model.nq}")
            return qpos, mocap
        frames = messages["/robot/sensors"]
        if not frames:
            raise ValueError("the log holds no sensor readings and no ground truth")
        qpos = np.tile(np.asarray(model.qpos0, np.float64), (len(frames), 1))
        for name, adr in encoders.items():
            qpos[:, adr] = [float(f["readings"][name][0]) for f in frames]
    except (KeyError, IndexError, TypeError, ValueError) as err:
        why = f"{type(err).__name__} {err}" if not isinstance(err, ValueError) else str(err)
        raise ValueError(f"the log's poses are damaged ({why[:160]})") from None
    return qpos, None


__all__ = ["CHUNK", "TOPICS", "LogError", "LogWriter", "poses", "read_log"]
