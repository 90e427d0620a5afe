"""What a robot reads and takes, declared once per robot, and the interface a user
implements to run a jaxenvs policy on their own hardware.

* :class:`RobotSpec` (:func:`spec_of`): a robot's observable sensors (name, size, unit,
  MuJoCo sensor kind; the privileged ones left out), its actuators (name and the ``ctrl``
  of actions -1 and +1) and the control period. It is derived from the robot module's
  declaration (:class:`~jaxenvs.robots.base.Robot`) and the task's timing, and it is what
  a robot announces in its hello message (:mod:`jaxenvs.deploy.wire`).
* :class:`SensorFrame`: one set of readings, with the robot's sequence number and clock.
* :class:`RobotLink`: the :class:`~typing.Protocol` a robot driver implements (connect,
  read the latest sensors, send a command, hold, close). :class:`jaxenvs.deploy.link.TcpRobot`
  implements it over the documented TCP messages; ``docs/robot_interface.md`` shows how to
  implement it, or the messages, for your own robot.
* :class:`HostTask`: the task's observation, actuator action, reward and termination on
  the host, computed by the task's OWN functions (:meth:`RobotTask.observation` of
  readings, ...), jitted once on the CPU, so that the loop driving a robot computes
  exactly what the simulator computed in training.

This module imports numpy and the standard library at import time; :class:`HostTask`
imports JAX when it is built.
"""

from __future__ import annotations

import dataclasses
import math
import types
from collections.abc import Mapping
from typing import Any, Protocol, runtime_checkable

import numpy as np

#: units of a sensor kind's reading; joint sensors depend on the joint (hinge or slide)
UNITS = {
    "framepos": "m",
    "framequat": "1",
    "gyro": "rad/s",
    "velocimeter": "m/s",
    "accelerometer": "m/s^2",
    "force": "N",
    "torque": "N m",
    "touch": "N",
}
#: the standard deviation of a simulated sensor's noise at ``--noise 1``, by kind and unit
NOISE_STD = {"m": 1e-3, "rad": 1e-3, "m/s": 1e-2, "rad/s": 1e-2, "1": 1e-3, "m/s^2": 5e-2}


@dataclasses.dataclass(frozen=True)
class SensorSpec:
    """One observable sensor: its reading is ``size`` float numbers in ``unit``."""

    name: str
    size: int
    unit: str
    kind: str


@dataclasses.dataclass(frozen=True)
class ActuatorSpec:
    """One actuator: ``low``/``high`` is the ``ctrl`` (its MJCF control) of actions -1, +1;
    the command map is linear between them."""

    name: str
    low: float
    high: float


@dataclasses.dataclass(frozen=True)
class RobotSpec:
    """What a robot reads and takes.

    Attributes:
      robot: the robot's name (its MJCF file's stem, e.g. ``"cartpole"``).
      env_id: the task it runs.
      sensors: the observable sensors, in the robot's declaration order.
      actuators: the actuators, in ``ctrl`` order.
      control_dt: seconds between two commands (the task's control period).
    """

    robot: str
    env_id: str
    sensors: tuple[SensorSpec, ...]
    actuators: tuple[ActuatorSpec, ...]
    control_dt: float

    def to_json(self) -> dict[str, Any]:
        """The spec as the hello message's fields (JSON types)."""
        return {
            "robot": self.robot,
            "env_id": self.env_id,
            "control_dt": self.control_dt,
            "sensors": [dataclasses.asdict(s) for s in self.sensors],
            "actuators": [dataclasses.asdict(a) for a in self.actuators],
        }

    @classmethod
    def from_json(cls, obj: Mapping[str, Any]) -> RobotSpec:
        """The spec of a hello message; ``ValueError`` naming the first bad field."""
        try:
            spec = cls(
                robot=str(obj["robot"]),
                env_id=str(obj["env_id"]),
                sensors=tuple(
                    SensorSpec(str(s["name"]), int(s["size"]), str(s["unit"]), str(s["kind"]))
                    for s in obj["sensors"]
                ),
                actuators=tuple(
                    ActuatorSpec(str(a["name"]), float(a["low"]), float(a["high"]))
                    for a in obj["actuators"]
                ),
                control_dt=float(obj["control_dt"]),
            )
        except (KeyError, TypeError, ValueError, OverflowError) as err:
            raise ValueError(f"bad robot description: {type(err).__name__} {err}") from None
        if not spec.control_dt > 0 or any(s.size < 1 for s in spec.sensors):
            raise ValueError("bad robot description: control_dt and sensor sizes must be > 0")
        return spec

    def sizes(self) -> dict[str, int]:
        """Sensor name -> reading size."""
        return {s.name: s.size for s in self.sensors}

    def check_matches(self, other: RobotSpec) -> None:
        """``ValueError`` naming the first difference in what the two robots read and
        take: sensor names and sizes, actuator names and command ranges (each actuator's
        ``ctrl`` at actions -1 and +1, to a relative 1e-6; a NaN never matches: a robot
        that would apply another force than the policy was trained with), control
        period."""
        if other.robot != self.robot:
            raise ValueError(f"the robot is a {other.robot}, the task needs a {self.robot}")
        if other.sizes() != self.sizes():
            raise ValueError(f"the robot's sensors {other.sizes()} differ from {self.sizes()}")
        names = [a.name for a in self.actuators]
        if [a.name for a in other.actuators] != names:
            raise ValueError(f"the robot's actuators differ from {names}")
        for want, have in zip(self.actuators, other.actuators, strict=True):
            same = all(
                math.isclose(a, b, rel_tol=1e-6, abs_tol=1e-9)
                for a, b in ((want.low, have.low), (want.high, have.high))
            )
            if not same:
                raise ValueError(
                    f"the robot's actuator {want.name} takes {have.low:g}..{have.high:g} at "
                    f"actions -1..1, the task's {want.low:g}..{want.high:g}"
                )
        if not abs(other.control_dt - self.control_dt) <= 1e-9:
            raise ValueError(
                f"the robot's control period {other.control_dt} s is not the task's "
                f"{self.control_dt} s"
            )


def _unit(robot: Any, sensor: Any) -> str:
    if sensor.joint is not None:
        linear = robot.joints[sensor.joint].kind == "slide"
        if sensor.kind == "jointpos":
            return "m" if linear else "rad"
        return "m/s" if linear else "rad/s"
    return UNITS.get(sensor.kind, "")


def command_ends(robot: Any) -> tuple[np.ndarray, np.ndarray]:
    """The ``ctrl`` of actions -1 and +1 on every actuator through the robot's own command
    map (:meth:`~jaxenvs.robots.base.Robot.command`, linear in the action), float64."""
    n = len(robot.actuators)
    low = np.asarray(robot.command(np.full(n, -1.0, np.float32)), np.float64)
    high = np.asarray(robot.command(np.full(n, 1.0, np.float32)), np.float64)
    return low, high


def spec_of(env: Any, env_id: str) -> RobotSpec:
    """The :class:`RobotSpec` of the task ``env`` (registered as ``env_id``) over a robot
    (its ``env.robot``): the robot's observable sensors, its actuators and command range,
    and ``env.control_dt``."""
    robot = getattr(env, "robot", None)
    if robot is None:
        raise ValueError(f"{env_id} is not a task over a robot (it has no robot declaration)")
    low, high = command_ends(robot)
    return RobotSpec(
        robot=robot.xml.stem,
        env_id=env_id,
        sensors=tuple(
            SensorSpec(s.name, s.dim, _unit(robot, s), s.kind)
            for s in robot.sensors.values()
            if not s.privileged and (s.from_state or robot.sensordata)
        ),
        actuators=tuple(
            ActuatorSpec(name, float(low[i]), float(high[i]))
            for i, name in enumerate(robot.actuators)
        ),
        control_dt=float(env.control_dt),
    )


@dataclasses.dataclass(frozen=True)
class SensorFrame:
    """One set of readings from a robot.

    Attributes:
      seq: the robot's sequence number (increasing by one per frame).
      stamp: the robot's clock when it read the sensors (seconds).
      readings: sensor name -> float64 array of the sensor's size.
      received: this computer's ``time.monotonic()`` when the frame arrived.
      acked: the sequence number of the last command the robot applied (-1: none).
    """

    seq: int
    stamp: float
    readings: dict[str, np.ndarray]
    received: float
    acked: int = -1


@runtime_checkable
class RobotLink(Protocol):
    """A robot as the deploy loop drives it. Implement it for your own hardware
    (``docs/robot_interface.md``), or speak :mod:`jaxenvs.deploy.wire` and use
    :class:`jaxenvs.deploy.link.TcpRobot`.

    Every method but :meth:`connect` must return within a fraction of the control period.
    Errors that end the run (the robot is gone, it sent something malformed) are raised as
    :class:`LinkError` with a one-line message naming the cause.
    """

    def connect(self) -> RobotSpec:
        """Open the link; return what the robot reads and takes."""
        ...

    def latest(self) -> SensorFrame | None:
        """The newest sensor frame received so far (``None`` before the first)."""
        ...

    def send(self, seq: int, action: np.ndarray) -> None:
        """Command the actuators: ``action`` in [-1, 1] per actuator (the robot applies its
        command map), tagged with the loop's sequence number ``seq``."""
        ...

    def hold(self, reason: str) -> None:
        """Safe stop: hold position (action 0) until told otherwise."""
        ...

    def close(self) -> None:
        """Release the link; safe to call twice."""
        ...


class LinkError(RuntimeError):
    """The link to the robot failed; the message is one line naming the cause."""


# ------------------------------------------------------------------------ task on the host
class HostTask:
    """The task's own functions on host arrays, jitted once (on the default device: the
    CPU, where the loop runs).

    * :meth:`observe`: ``env.observation(readings, task_state)``: the noiseless
      observation of the sensors' readings and the task's own state;
    * :meth:`actuator_action`: ``env.actuator_action(action)``: the policy's action as an
      action in [-1, 1] per actuator; :meth:`actuator_command`:
      ``env.actuator_command(action, previous)``: the one to send, given the one sent
      before (a task that filters its commands);
    * :meth:`task_state`, :meth:`reward`, :meth:`terminated`: of the simulator's ground
      truth (``qpos``, ``qvel``, ``mocap_pos``), for a simulated robot that publishes it;
    * a task's optional hooks: ``task_input_shape``, ``with_task_input(task, value)``
      (:meth:`with_input`: the operator's input, e.g. a joystick command, into the task
      state), ``action_history`` and ``with_action_history(task, actions)``
      (:meth:`with_action_history`: for an observation holding the last
      ``action_history`` actions), ``tracking_errors(prev, data, task)``
      (:meth:`tracking`: errors of a ground-truth step against the input in force), and
      ``with_clock(task, steps)`` and ``prior_action(task, action)`` (:meth:`with_clock`,
      :meth:`prior_action`: a task whose state holds the control steps since the start
      and whose action adds a prior to the policy's, e.g. ``HexapodJoystickRough-v0``'s
      gait prior; identities by default).
    """

    def __init__(self, env: Any, seed: int = 0) -> None:
        import jax

        from jaxenvs.core.xla import jit

        self.env = env
        self._extras = env.reset(jax.random.key(seed)).extras
        self._params = env.default_params
        self._obs = jit(env.observation)
        self._act = jit(env.actuator_action)
        self._command = jit(env.actuator_command)
        self._truth_fns = jit(self._of_truth)
        self._input = jit(env.with_task_input)
        self._history = jit(env.with_action_history)
        self._clock = jit(env.with_clock)
        self._prior = jit(env.prior_action)
        #: how many of the last actions the observation holds (the task's
        #: ``action_history``; 1 for a task without one, which ignores them)
        self.action_history = int(env.action_history)
        self._tracking = jit(self._tracking_of(env.tracking_errors))
        #: the observation needs a task state that a reset does not give (known after
        #: :meth:`warm`): the ground truth's, or a task input
        self.needs_input = False

    @property
    def zero_action(self) -> np.ndarray:
        """An action of the policy's shape and dtype, all zeros."""
        return np.zeros(self.env.action_shape, np.int32 if self.env.discrete else np.float32)

    @property
    def zero_history(self) -> np.ndarray:
        """``action_history`` zero actions (before the first command), the most recent
        first."""
        return np.stack([self.zero_action] * self.action_history)

    @staticmethod
    def pushed(history: np.ndarray, action: np.ndarray) -> np.ndarray:
        """``history`` (the most recent first) after ``action`` was sent."""
        return np.concatenate([np.asarray(action, history.dtype)[None], history[:-1]])

    def warm(self, sizes: Mapping[str, int], truth: Mapping[str, np.ndarray]) -> tuple[int, ...]:
        """Compile every function once (before a real-time loop) on zero inputs of the
        readings' ``sizes`` and of the ground truth's shapes; the shape of the task's input
        (``--command``): the task's ``task_input_shape``, else that of its own state (``()``
        when it has none or several parts)."""
        readings = {name: np.zeros(size) for name, size in sizes.items()}
        self.actuator_command(self.zero_action, self.zero_command)
        task, _, _ = self.of_truth(truth, truth, self.zero_action)
        self._task0 = task
        self.observe(readings, task)
        try:
            self.observe(readings, self._extras)
            self.needs_input = False
        except (TypeError, ValueError):
            self.needs_input = True  # the task's state must come from the truth or a command
        import jax

        task = self.with_action_history(self.with_clock(task, 0), self.zero_history)
        self.observe(readings, task)
        self.prior_action(task, self.zero_action)
        self.tracking(truth, truth, task)
        leaves = jax.tree.leaves(task)
        shape = self.env.task_input_shape
        if shape is None and len(leaves) != 1:
            return ()
        shape = tuple(np.shape(leaves[0])) if shape is None else tuple(shape)
        value = np.zeros(shape, np.float32)  # a task input (--command)
        self.observe(
            readings, self.with_action_history(self.with_input(task, value), self.zero_history)
        )
        return shape

    def with_input(self, task: Any, value: np.ndarray) -> Any:
        """The task state ``task`` with the task input ``value`` in force (the task's
        ``with_task_input``; without one the input is the whole task state)."""
        return self._input(task, value)

    def with_action_history(self, task: Any, actions: np.ndarray) -> Any:
        """The task state holding ``actions``, the last ``action_history`` actions applied
        (the most recent first; the policy's, with a task's :meth:`prior_action` where it
        has one, before a task's command filter),
        for a task whose observation holds them (its ``with_action_history``); ``task``
        itself otherwise."""
        return self._history(task, actions)

    def with_clock(self, task: Any, steps: int) -> Any:
        """The task state at ``steps`` control periods since the drive's start, missed
        ones included (the loop's tick index; the task's ``with_clock``: ``task`` itself
        for a task without a clock)."""
        return self._clock(task, np.int32(steps))

    def prior_action(self, task: Any, action: np.ndarray) -> np.ndarray:
        """The action to apply for the policy's ``action`` in task state ``task`` (the
        task's ``prior_action``: what its env applies and its observation's history
        holds; ``action`` itself for a task without a prior)."""
        return np.asarray(self._prior(task, action), np.asarray(action).dtype)

    @staticmethod
    def _tracking_of(fn: Any) -> Any:
        def tracking(prev: Any, truth: Any, task: Any) -> Any:
            p, d = types.SimpleNamespace(**prev), types.SimpleNamespace(**truth)
            return fn(p, d, task)

        return tracking

    def tracking(
        self, prev: Mapping[str, np.ndarray], truth: Mapping[str, np.ndarray], task: Any
    ) -> dict[str, float]:
        """The task's tracking errors (its ``tracking_errors``: e.g. a joystick's velocity
        error against the command of ``task``) of the ground-truth step ``prev -> truth``;
        ``{}`` for a task without them."""
        return {k: float(v) for k, v in self._tracking(dict(prev), dict(truth), task).items()}

    def _of_truth(self, prev: Any, truth: Any, action: Any) -> Any:
        p, d = types.SimpleNamespace(**prev), types.SimpleNamespace(**truth)
        task = self.env.task_state(d, self._extras)
        try:
            reward = self.env.transition_reward(p, d, action, self._extras, self._params)
        except AttributeError:  # the reward needs more than the pose (e.g. servo forces)
            reward = float("nan")
        return task, reward, self.env.terminal(d, self._extras, self._params)

    def observe(self, readings: Mapping[str, np.ndarray], task_state: Any) -> np.ndarray:
        """The observation (float32) of ``readings`` and ``task_state``."""
        return np.asarray(self._obs(dict(readings), task_state), np.float32)

    def actuator_action(self, action: np.ndarray) -> np.ndarray:
        """The policy's action as one action in [-1, 1] per actuator (float64)."""
        return np.asarray(self._act(action), np.float64)

    @property
    def zero_command(self) -> np.ndarray:
        """The command sent before the first (each actuator's action 0), float64."""
        return np.zeros_like(self.actuator_action(self.zero_action))

    def actuator_command(self, action: np.ndarray, previous: np.ndarray) -> np.ndarray:
        """The command to send for the policy's action when ``previous`` was sent the
        step before (float64): the policy's action per actuator, filtered where the task
        filters its commands."""
        return np.asarray(self._command(action, np.asarray(previous, np.float32)), np.float64)

    @property
    def default_task_state(self) -> Any:
        """The task's own state at a reset with the loop's seed (e.g. ``NoExtras``), as
        :meth:`warm`'s ground truth gives it once warmed."""
        return getattr(self, "_task0", self._extras)

    def of_truth(
        self, prev: Mapping[str, np.ndarray], truth: Mapping[str, np.ndarray], action: np.ndarray
    ) -> tuple[Any, float, bool]:
        """(task state, reward, terminated) of the ground truth ``truth`` reached from
        ``prev`` with ``action`` in force (each a mapping of ``qpos``, ``qvel``,
        ``mocap_pos``); the reward is NaN for a task whose reward needs more than the
        ground truth holds (``HexapodJoystick-v0``: the servos' forces)."""
        task, reward, term = self._truth_fns(dict(prev), dict(truth), action)
        return task, float(reward), bool(term)


__all__ = [
    "ActuatorSpec",
    "HostTask",
    "LinkError",
    "RobotLink",
    "RobotSpec",
    "SensorFrame",
    "SensorSpec",
    "spec_of",
]
