"""What a robot is, apart from any task: its MJCF, joints, actuators, sensors, randomisable
physics.

A :class:`Robot` is built from one MJCF file. It knows

* how to build its :class:`~jaxenvs.physics.sim.Sim` (:meth:`Robot.make_sim`: timestep, substeps,
  model edits, whether MuJoCo evaluates the MJCF's sensors in each physics step);
* its joints (:attr:`Robot.joints`: name -> qpos/qvel addresses), its actuators and their
  COMMAND MAP (:meth:`Robot.command`: an action in [-1, 1] per actuator -> ``ctrl``, linear
  over each actuator's control range; :attr:`Robot.command_range` is the ``ctrl`` of -1
  and +1);
* the sensors a real robot of this kind carries, declared in the MJCF as MuJoCo
  ``<sensor>`` elements (:attr:`Robot.sensors`), of which those a real robot cannot
  measure are PRIVILEGED (named in :attr:`Robot.privileged`: simulator only, e.g. the
  body's world velocity); :meth:`Robot.sense` reads them all;
* its randomisable physical fields: :attr:`Robot.fields` (MuJoCo model field names),
  :meth:`Robot.default_fields` and :meth:`Robot.sample_fields` with a frozen
  :class:`Randomization` config of ranges.

**Readings at the current state.** After ``mjx.step`` or ``mj_step``, ``sensordata`` (as
``xpos``/``xquat``) comes from the forward pass at the START of the last physics substep,
one substep older than ``qpos``/``qvel``. :meth:`Robot.sense` therefore evaluates every
sensor that is a function of the state (``jointpos``, ``jointvel``, and ``framepos``,
``framequat``, ``gyro``, ``velocimeter`` of a site at a free-floating body's origin with
the body's orientation) from ``qpos``/``qvel`` with ``jax.numpy``: the value MuJoCo's
sensor has after ``mj_forward`` at that state (``tests/robots/test_robots.py`` checks it for
every robot on random states). Every other sensor (``accelerometer``, forces, touch) is
read from ``sensordata`` and is ONE SUBSTEP OLD; it is available only from a robot built
with ``sensordata=True``, whose Sim has MuJoCo evaluate the MJCF's sensors. Otherwise the
Sim sets ``mjDSBL_SENSOR``: MJX and MuJoCo C evaluate every MJCF sensor in each physics
substep (the accelerometer with an extra RNE pass), which cost the walker 6-11 % of its MJX
step throughput and 4-8 % of MuJoCo C's step time (2-core machine, 128 envs, sensors on vs
off, interleaved repeats, median and minimum), and no shipped task reads ``sensordata``.

Everything on device is ``jax.numpy`` over ``data`` fields: traceable, vmappable, the same
under MJX and the C engine.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any, ClassVar

import jax
import jax.numpy as jnp
import mujoco
import numpy as np

from jaxenvs.physics.sim import Sim, SpecSource

Readings = dict[str, jax.Array]

_SENS = mujoco.mjtSensor
_OBJ = mujoco.mjtObj
#: sensor types evaluated from qpos/qvel (the value at the current state)
STATE_SENSORS = ("jointpos", "jointvel", "framepos", "framequat", "gyro", "velocimeter")
#: of those, the ones of a site on a free-floating body
_BODY_SENSORS = STATE_SENSORS[2:]


def sensor_kind(sensor_type: int) -> str:
    """MuJoCo's name of a sensor type without its prefix (``mjSENS_GYRO`` -> ``"gyro"``)."""
    return _SENS(sensor_type).name.removeprefix("mjSENS_").lower()


@dataclasses.dataclass(frozen=True)
class Joint:
    """One joint of a robot.

    Attributes:
      name: the MJCF joint name.
      qpos: address of its first coordinate in ``qpos``.
      qvel: address of its first degree of freedom in ``qvel``.
      kind: ``"free"``, ``"ball"``, ``"slide"`` or ``"hinge"``.
      range: ``(low, high)`` of a limited joint (rad or m), ``None`` if unlimited.
    """

    name: str
    qpos: int
    qvel: int
    kind: str
    range: tuple[float, float] | None = None


@dataclasses.dataclass(frozen=True)
class Sensor:
    """One MJCF ``<sensor>``.

    Attributes:
      name: the MJCF sensor name (the key of its reading).
      kind: MuJoCo's sensor type (``"jointpos"``, ``"gyro"``, ``"accelerometer"``, ...).
      adr, dim: its slice of ``sensordata``.
      privileged: simulator only; a real robot of this kind cannot measure it.
      from_state: evaluated from ``qpos``/``qvel`` (else read from ``sensordata``).
      joint: for joint sensors, the joint it reads.
    """

    name: str
    kind: str
    adr: int
    dim: int
    privileged: bool
    from_state: bool
    joint: str | None = None


@dataclasses.dataclass(frozen=True)
class Randomization:
    """Base of a robot family's randomisation config (frozen ``(low, high)`` ranges).

    A task config inherits its robot's subclass (before :class:`~jaxenvs.core.TaskConfig`)
    so that the ranges are config fields (``make(id, mass_scale=(0.9, 1.1))``);
    :meth:`validate` checks them and calls the next class's ``validate``.
    """

    def validate(self) -> None:
        parent = getattr(super(), "validate", None)
        if parent is not None:
            parent()
        self.check_ranges()

    def check_ranges(self) -> None:
        """Raise :class:`~jaxenvs.config.ConfigError` naming a bad range."""


def _kinds() -> dict[int, str]:
    j = mujoco.mjtJoint
    return {
        int(j.mjJNT_FREE): "free",
        int(j.mjJNT_BALL): "ball",
        int(j.mjJNT_SLIDE): "slide",
        int(j.mjJNT_HINGE): "hinge",
    }


def _name(model: mujoco.MjModel, obj: Any, i: int) -> str:
    return mujoco.mj_id2name(model, obj, i) or ""


class Robot:
    """One robot: its MJCF, joints, actuators, command map, sensors, randomisable fields.

    Subclasses set :attr:`xml` and may override :meth:`command`, :attr:`privileged`,
    :attr:`fields` and :meth:`sample_fields`.

    Args:
      sensordata: have MuJoCo evaluate the MJCF's sensors in each physics step (needed to
        read the sensors :meth:`sense` takes from ``sensordata``, e.g. an accelerometer);
        off by default (the Sim sets ``mjDSBL_SENSOR``).
    """

    #: the MJCF file
    xml: ClassVar[Path]
    #: names of the sensors a real robot of this kind cannot measure
    privileged: ClassVar[frozenset[str]] = frozenset()
    #: the MuJoCo model fields that :meth:`sample_fields` randomises
    fields: ClassVar[tuple[str, ...]] = ()

    def __init__(self, sensordata: bool = False) -> None:
        self.sensordata = bool(sensordata)
        #: the host model of the MJCF (ids match the Sim's models)
        self.model = mujoco.MjModel.from_xml_path(str(self.xml))
        m = self.model
        kinds = _kinds()
        #: joints by name, in MJCF order
        self.joints: dict[str, Joint] = {
            _name(m, _OBJ.mjOBJ_JOINT, i): Joint(
                _name(m, _OBJ.mjOBJ_JOINT, i),
                int(m.jnt_qposadr[i]),
                int(m.jnt_dofadr[i]),
                kinds[int(m.jnt_type[i])],
                (float(m.jnt_range[i, 0]), float(m.jnt_range[i, 1])) if m.jnt_limited[i] else None,
            )
            for i in range(m.njnt)
        }
        #: actuator names, in ``ctrl`` order
        self.actuators: tuple[str, ...] = tuple(
            _name(m, _OBJ.mjOBJ_ACTUATOR, i) for i in range(m.nu)
        )
        low, high = np.asarray(m.actuator_ctrlrange, np.float64).T
        self._centred = bool(np.all(low == -high))
        self._mid = np.asarray((low + high) / 2, np.float32)
        self._half = np.asarray((high - low) / 2, np.float32)
        #: sensors by name, in ``sensordata`` order
        self.sensors: dict[str, Sensor] = {}
        self._free: dict[str, Joint] = {}  # the free joint of each frame/velocity sensor
        for i in range(m.nsensor):
            sensor = self._declare(i)
            self.sensors[sensor.name] = sensor
        unknown = sorted(self.privileged - set(self.sensors))
        if unknown:
            raise ValueError(f"{self.xml.name}: privileged sensors {unknown} are not declared")
        self._encoders = self._joint_sensors("jointpos")
        self._rates = self._joint_sensors("jointvel")

    # ---------------------------------------------------------------- declaration
    def _declare(self, i: int) -> Sensor:
        m = self.model
        name = _name(m, _OBJ.mjOBJ_SENSOR, i)
        kind = sensor_kind(int(m.sensor_type[i]))
        if not name:
            raise ValueError(f"{self.xml.name}: sensor {i} ({kind}) has no name")
        obj = int(m.sensor_objid[i])
        if kind in STATE_SENSORS and m.sensor_cutoff[i] > 0:
            raise ValueError(f"{self.xml.name}: sensor {name!r}: a cutoff is not evaluated")
        joint = None
        if kind in ("jointpos", "jointvel"):
            joint = _name(m, _OBJ.mjOBJ_JOINT, obj)
            if self.joints[joint].kind not in ("hinge", "slide"):
                raise ValueError(f"{self.xml.name}: sensor {name!r} reads a non-scalar joint")
        elif kind in _BODY_SENSORS:
            self._free[name] = self._check_body_site(name, i)
        return Sensor(
            name=name,
            kind=kind,
            adr=int(m.sensor_adr[i]),
            dim=int(m.sensor_dim[i]),
            privileged=name in self.privileged,
            from_state=kind in STATE_SENSORS,
            joint=joint,
        )

    def _check_body_site(self, name: str, i: int) -> Joint:
        """A frame or velocity sensor must sit on a site at a free body's origin, unrotated,
        with no reference frame: then its value is a function of that joint's qpos/qvel."""
        m = self.model
        site = int(m.sensor_objid[i])
        ok = int(m.sensor_objtype[i]) == _OBJ.mjOBJ_SITE and int(m.sensor_refid[i]) == -1
        if ok:
            body = int(m.site_bodyid[site])
            first = int(m.body_jntadr[body])
            ok = (
                int(m.body_jntnum[body]) == 1
                and int(m.jnt_type[first]) == mujoco.mjtJoint.mjJNT_FREE
                and np.allclose(m.site_pos[site], 0)
                and np.allclose(m.site_quat[site], [1, 0, 0, 0])
            )
        if not ok:
            raise ValueError(
                f"{self.xml.name}: sensor {name!r} must be on an unrotated site at a free "
                "body's origin with no reference frame (its value is then the free joint's "
                "state)"
            )
        return self.joints[_name(m, _OBJ.mjOBJ_JOINT, first)]

    def _joint_sensors(self, kind: str) -> tuple[str, ...]:
        """Names of the ``kind`` sensors of the scalar joints, in joint order."""
        by_joint = {s.joint: s.name for s in self.sensors.values() if s.kind == kind}
        return tuple(by_joint[j] for j in self.joints if j in by_joint)

    # ---------------------------------------------------------------- simulation
    def make_sim(
        self,
        timestep: float,
        substeps: int,
        edit: Callable[[mujoco.MjModel], None] | None = None,
        scene: SpecSource | None = None,
    ) -> Sim:
        """This robot's Sim, of its MJCF or of a ``scene`` holding it
        (:class:`jaxenvs.scenes.Scene`): ``edit`` applied to the host model, then (unless
        built with ``sensordata=True``) sensor evaluation turned off (``mjDSBL_SENSOR``)."""
        source = self.xml if scene is None else scene
        if self.sensordata:
            return Sim(source, timestep=timestep, substeps=substeps, edit=edit)

        def edit_and_silence(model: mujoco.MjModel) -> None:
            if edit is not None:
                edit(model)
            model.opt.disableflags |= mujoco.mjtDisableBit.mjDSBL_SENSOR

        return Sim(source, timestep=timestep, substeps=substeps, edit=edit_and_silence)

    def default_fields(self, sim: Sim) -> dict[str, jax.Array]:
        """The values of :attr:`fields` in ``sim``'s device model (the default params)."""
        return sim.default_fields(self.fields)

    def sample_fields(
        self, key: jax.Array, fields: Mapping[str, jax.Array], config: Any
    ) -> dict[str, jax.Array]:
        """Fields drawn from ``config``'s ranges around ``fields`` (the defaults)."""
        del key, config
        return dict(fields)

    # ---------------------------------------------------------------- commands
    @property
    def force_range(self) -> tuple[np.ndarray, np.ndarray]:
        """Each actuator's force (or torque) limits, -inf/inf where it has none."""
        m = self.model
        low, high = np.asarray(m.actuator_forcerange, np.float64).T
        limited = np.asarray(m.actuator_forcelimited, bool)
        return np.where(limited, low, -np.inf), np.where(limited, high, np.inf)

    @property
    def command_range(self) -> tuple[np.ndarray, np.ndarray]:
        """The ``ctrl`` of actions -1 and +1 (float32, one entry per actuator)."""
        return self._mid - self._half, self._mid + self._half

    def command(self, action: jax.Array) -> jax.Array:
        """``ctrl`` of actions in [-1, 1]: linear over each actuator's control range
        (``action * half-range`` where the ranges are centred on 0)."""
        n = action.shape[-1]
        if self._centred:
            return action * self._half[:n]
        return action * self._half[:n] + self._mid[:n]

    # ---------------------------------------------------------------- sensing
    def sense(self, data: Any) -> Readings:
        """Every sensor's reading by name, at ``data``'s state (see the module docstring:
        state sensors from ``qpos``/``qvel``; others from ``sensordata``, one substep old,
        only with ``sensordata=True``)."""
        out: Readings = {}
        for s in self.sensors.values():
            if s.from_state:
                out[s.name] = self._evaluate(s, data)
            elif self.sensordata:
                out[s.name] = data.sensordata[s.adr : s.adr + s.dim]
        return out

    def _evaluate(self, s: Sensor, data: Any) -> jax.Array:
        if s.joint is not None:
            j = self.joints[s.joint]
            if s.kind == "jointpos":
                return data.qpos[j.qpos : j.qpos + 1]
            return data.qvel[j.qvel : j.qvel + 1]
        free = self._free[s.name]
        if s.kind == "framepos":
            return data.qpos[free.qpos : free.qpos + 3]
        if s.kind == "framequat":
            return data.qpos[free.qpos + 3 : free.qpos + 7]
        if s.kind == "gyro":
            return data.qvel[free.qvel + 3 : free.qvel + 6]
        # velocimeter: the origin's world velocity in the body frame
        rot = quat_to_mat(data.qpos[free.qpos + 3 : free.qpos + 7])
        return rot.T @ data.qvel[free.qvel : free.qvel + 3]

    @property
    def encoders(self) -> tuple[str, ...]:
        """Names of the joint position sensors, in joint order."""
        return self._encoders

    def joint_pos(self, readings: Mapping[str, jax.Array]) -> jax.Array:
        """The joint position sensors' readings stacked in joint order (last axis)."""
        return jnp.concatenate([readings[n] for n in self._encoders], axis=-1)

    def joint_vel(self, readings: Mapping[str, jax.Array]) -> jax.Array:
        """The joint velocity sensors' readings stacked in joint order (last axis)."""
        return jnp.concatenate([readings[n] for n in self._rates], axis=-1)

    def observable(self) -> tuple[str, ...]:
        """Names of the sensors a real robot has (every sensor but the privileged)."""
        return tuple(n for n, s in self.sensors.items() if not s.privileged)


def quat_to_mat(q: jax.Array) -> jax.Array:
    """Rotation matrix (body -> world) of a unit quaternion ``(w, x, y, z)``."""
    w, x, y, z = q[0], q[1], q[2], q[3]
    return jnp.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
            [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
            [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
        ]
    )


def gravity_in_body(quat: jax.Array) -> jax.Array:
    """The gravity direction (unit, world -z) in the body frame of orientation ``quat``."""
    return quat_to_mat(quat).T @ jnp.array([0.0, 0.0, -1.0])


def world_to_body(quat: jax.Array, v: jax.Array) -> jax.Array:
    """A world-frame vector ``v`` (3,) in the body frame of orientation ``quat``."""
    return quat_to_mat(quat).T @ v


class RobotTask:
    """Mixin for an :class:`~jaxenvs.core.Env` over one robot (put it before ``Env``).

    The task sets ``self.robot`` and ``self._params`` (a params pytree whose ``model`` holds
    :meth:`Robot.default_fields`); this gives ``default_params`` and a ``sample_params``
    that redraws ``model`` from the robot's ranges in the task's config.

    The observation is :meth:`observation` of the robot's readings and the task's own
    state (:meth:`task_state`), so that a loop driving a real robot can compute it from
    readings received over a link: ``_observe`` is
    ``observation(robot.sense(data), task_state(data, extras))`` (a task adds its
    observation noise around it).
    """

    robot: Robot
    _params: Any
    config: Any

    def observation(self, readings: Readings, task: Any) -> jax.Array:
        """The noiseless observation of the robot's ``readings`` (sensor name -> reading)
        and the task's own state ``task`` (:meth:`task_state`)."""
        raise NotImplementedError(f"{type(self).__name__} must define observation()")

    def task_state(self, data: Any, extras: Any) -> Any:
        """What the observation needs besides the readings (a target, a command); the
        task's ``extras`` unless the task says otherwise."""
        del data
        return extras

    def actuator_action(self, action: jax.Array) -> jax.Array:
        """The policy's ``action`` as an action in [-1, 1] per actuator (what the robot's
        command map takes); the action itself unless the task says otherwise."""
        return jnp.asarray(action, jnp.float32)

    def actuator_command(self, action: jax.Array, previous: jax.Array) -> jax.Array:
        """The action in [-1, 1] per actuator to send for the policy's ``action``, where
        ``previous`` is the one sent the control step before (zeros before the first):
        :meth:`actuator_action` unless the task filters its commands
        (``HexapodJoystick-v0``'s ``action_filter``). A deploy loop sends this; the env
        applies the same."""
        del previous
        return self.actuator_action(action)

    # ------------------------------------------------ what a deploy loop calls (public)
    #: how many of the policy's last actions the observation holds (1: none but what the
    #: task state says; the joystick's ``action_delay_max + 1``)
    action_history: int = 1
    #: the shape of the task's input in a deploy loop (``jaxenvs deploy --command``);
    #: ``None``: the shape of the task state itself
    task_input_shape: tuple[int, ...] | None = None

    def with_task_input(self, task: Any, value: Any) -> Any:
        """The task state ``task`` with a deploy loop's task input ``value`` in force (a
        command, a target); default: the input is the whole task state."""
        del task
        return value

    def with_action_history(self, task: Any, actions: Any) -> Any:
        """The task state holding ``actions``, the policy's last :attr:`action_history`
        actions (the most recent first); default: ``task`` (the observation holds none)."""
        del actions
        return task

    def with_clock(self, task: Any, steps: Any) -> Any:
        """The task state at ``steps`` control periods since a deploy loop's start, for a
        task whose state holds a clock (``HexapodJoystickRough-v0``'s gait prior);
        default: ``task`` (no clock)."""
        del steps
        return task

    def prior_action(self, task: Any, action: Any) -> Any:
        """The action the env applies (and an observation's history holds) for the
        policy's ``action`` in task state ``task``, for a task that adds a prior to it
        (``HexapodJoystickRough-v0``'s gait prior); default: ``action`` itself."""
        del task
        return action

    def tracking_errors(self, prev: Any, data: Any, task: Any) -> dict[str, jax.Array]:
        """The task's tracking errors of the step ``prev -> data`` (one control period
        apart) under the task state ``task`` (a joystick's velocity errors against its
        command); default: none."""
        del prev, data, task
        return {}

    def transition_reward(
        self, prev: Any, data: Any, action: Any, extras: Any, params: Any
    ) -> jax.Array:
        """The reward of the step ``prev -> data`` under ``action`` (the task's
        ``_reward``), for states that may hold only some fields (a robot's ground truth:
        raises ``AttributeError`` naming a missing one)."""
        reward, _ = self._reward(prev, data, action, extras, params)  # type: ignore[attr-defined]
        return reward

    def terminal(self, data: Any, extras: Any, params: Any) -> jax.Array:
        """Whether ``data`` is a terminal state (the task's ``_terminated``)."""
        return self._terminated(data, extras, params)  # type: ignore[attr-defined]

    def _observe(self, key: jax.Array, data: Any, extras: Any, params: Any) -> jax.Array:
        del key, params
        return self.observation(self.robot.sense(data), self.task_state(data, extras))

    @property
    def default_params(self) -> Any:
        return self._params

    def sample_params(self, key: jax.Array) -> Any:
        """Params with ``model`` drawn by the robot from the config's ranges."""
        model = self.robot.sample_fields(key, self._params.model, self.config)
        return self._params.replace(model=model)
