"""The task's own input in a deploy loop (a target, a joystick command): a script read and
checked whole before the robot moves, or lines typed while it runs; and the range the task
was trained on, which every input must respect.

A script holds lines ``T v1 v2 ...`` (``#`` starts a comment): from ``T`` seconds after the
start the input is ``(v1, v2, ...)``. Every number is finite, the first ``T`` is 0, the
times increase and every line has as many values; :meth:`CommandInput.expect` then checks
the values' count and range against the task (:func:`input_range`).
"""

from __future__ import annotations

import dataclasses
import math
import sys
import threading
from pathlib import Path
from typing import Any

import numpy as np

#: the largest command script read (bytes)
MAX_SCRIPT = 16 << 20
F32_MAX = float(np.finfo(np.float32).max)


@dataclasses.dataclass(frozen=True)
class InputRange:
    """The inputs a task was trained on: a box ``low``..``high`` per value, or (with
    ``radius``) a disk around the origin of that radius on the first two values."""

    low: tuple[float, ...] = ()
    high: tuple[float, ...] = ()
    radius: float | None = None

    def problem(self, value: np.ndarray) -> str | None:
        """Why ``value`` is outside the range, in a few words (``None`` when inside)."""
        v = np.asarray(value, np.float64)
        if self.radius is not None:
            r = float(np.hypot(v[0], v[1]))
            if r > self.radius + 1e-6:
                return f"{r:.3g} from the centre, the task's disk has radius {self.radius:g}"
        for i, (lo, hi) in enumerate(zip(self.low, self.high, strict=True)):
            if not lo - 1e-6 <= v[i] <= hi + 1e-6:
                return f"value {i + 1} ({v[i]:g}) is outside [{lo:g}, {hi:g}]"
        return None


def input_range(env: Any) -> InputRange | None:
    """The range of ``env``'s task input, from the config it was trained with: a target
    disk (a config's ``target_radius``, and the top of its ``target_radius_range``), or a
    velocity command's box (``vx_range``, ``vy_range``, ``yaw_range``); ``None`` when the
    config states none."""
    config: Any = getattr(env, "config", None)
    if hasattr(config, "target_radius"):
        radius = float(config.target_radius)
        top = getattr(config, "target_radius_range", None)
        return InputRange(radius=max(radius, float(top[1])) if top else radius)
    names = ("vx_range", "vy_range", "yaw_range")
    if all(hasattr(config, n) for n in names):
        ranges = [tuple(map(float, getattr(config, n))) for n in names]
        return InputRange(tuple(r[0] for r in ranges), tuple(r[1] for r in ranges))
    return None


def _numbers(line: str) -> list[float]:
    return [float(f) for f in line.split("#")[0].split()]


def read_script(source: str) -> list[tuple[float, np.ndarray]]:
    """The ``(T, values)`` of a script file, checked whole (module docstring);
    ``ValueError`` naming the file, the line and the problem."""
    path = Path(source)
    try:
        if path.stat().st_size > MAX_SCRIPT:
            raise ValueError(f"{source}: a command script of more than {MAX_SCRIPT} bytes")
        lines = path.read_text().splitlines()
    except (OSError, UnicodeDecodeError) as err:
        why = getattr(err, "strerror", None) or type(err).__name__
        raise ValueError(f"cannot read the command script {source}: {why}") from None
    script: list[tuple[float, np.ndarray]] = []
    for n, line in enumerate(lines, 1):
        try:
            fields = _numbers(line)
        except ValueError:
            raise ValueError(f"{source}:{n}: expected 'T v1 v2 ...' numbers") from None
        if not fields:
            continue
        where = f"{source}:{n}"
        if len(fields) < 2:
            raise ValueError(f"{where}: expected 'T v1 v2 ...' numbers (a time and a value)")
        if not all(math.isfinite(f) for f in fields):
            raise ValueError(f"{where}: every number must be finite")
        if any(abs(f) > F32_MAX for f in fields[1:]):
            raise ValueError(f"{where}: a value does not fit a 32-bit float")
        t, values = fields[0], np.asarray(fields[1:], np.float32)
        if not script and t != 0:
            raise ValueError(f"{where}: the command script must start at 0 s, not {t:g}")
        if script and t <= script[-1][0]:
            raise ValueError(f"{where}: times must increase ({t:g} s after {script[-1][0]:g} s)")
        if script and values.size != script[0][1].size:
            raise ValueError(
                f"{where}: {values.size} values, the first line has {script[0][1].size}"
            )
        script.append((t, values))
    if not script:
        raise ValueError(f"{source}: the command script holds no command")
    return script


class CommandInput:
    """The task's input from a script file (:func:`read_script`) or, for ``-``, from lines
    ``v1 v2 ...`` typed on standard input as it runs (each holds until the next; a line
    that is not numbers, of another size or outside the task's range is ignored with a
    message)."""

    def __init__(self, source: str) -> None:
        self._lock = threading.Lock()
        self._value: np.ndarray | None = None
        self._script: list[tuple[float, np.ndarray]] = []
        self._stdin_closed = threading.Event()
        #: the task input's size and range, once :meth:`expect` said them
        self.size: int | None = None
        self.range: InputRange | None = None
        if source == "-":
            threading.Thread(target=self._read_stdin, daemon=True).start()
        else:
            self._script = read_script(source)

    def expect(self, shape: tuple[int, ...], env_id: str, bounds: InputRange | None = None) -> None:
        """Check the script's values against the task input's ``shape`` and ``bounds``
        (one line naming the first command that does not fit)."""
        if len(shape) != 1:
            raise ValueError(f"{env_id} takes no task input (--command)")
        self.size, self.range = shape[0], bounds
        for t, value in self._script:
            if value.shape != shape:
                raise ValueError(
                    f"the command at {t:g} s has {value.size} values, {env_id} takes {shape[0]}"
                )
            why = None if bounds is None else bounds.problem(value)
            if why is not None:
                raise ValueError(f"the command at {t:g} s is outside {env_id}'s range: {why}")

    def _typed(self, line: str) -> np.ndarray | str:
        """A typed line's value, or why it is ignored."""
        try:
            value = np.asarray([float(f) for f in line.split()], np.float32)
        except ValueError:
            return "expected numbers"
        if not np.all(np.isfinite(value)):
            return "expected finite numbers"
        if self.size is not None and value.size != self.size:
            return f"expected {self.size} numbers"
        why = None if self.range is None else self.range.problem(value)
        return value if why is None else f"outside the task's range: {why}"

    def _read_stdin(self) -> None:
        try:
            for line in sys.stdin:
                if not line.strip():
                    continue
                value = self._typed(line)
                if isinstance(value, str):
                    print(f"ignored command {line.strip()[:80]!r}: {value}", file=sys.stderr)
                    continue
                with self._lock:
                    self._value = value
        finally:
            self._stdin_closed.set()

    @property
    def exhausted(self) -> bool:
        """No input will come any more (``-``: standard input has ended; the last typed
        value, if any, holds)."""
        return self._stdin_closed.is_set()

    def at(self, t: float) -> np.ndarray | None:
        """The input ``t`` seconds after the start (``None`` before the first)."""
        if not self._script:
            with self._lock:
                return self._value
        current = None
        for start, value in self._script:
            if start <= t:
                current = value
        return current


__all__ = ["MAX_SCRIPT", "CommandInput", "InputRange", "input_range", "read_script"]
