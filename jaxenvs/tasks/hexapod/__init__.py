"""The hexapod tasks over :mod:`jaxenvs.robots.hexapod`: one family, one base.

===========================  ===========================================================
``HexapodWalk-v0``           walk from target to target (a new one drawn on arrival);
                             falls end the episode (:mod:`.walk`)
``HexapodJoystick-v0``       follow a velocity command from the encoders and IMU only
                             (:mod:`.joystick`)
``HexapodOneLeg-v0``         put one leg's foot tip on a reachable target; no contacts
                             (:mod:`.one_leg`)
``HexapodJoystickRough-v0``  the joystick on a terrain of levels x types with a per-env
                             level curriculum; a blind policy (:mod:`.rough`)
``HexapodWalkRough-v0``      the walker on the same terrain and curriculum, its targets
                             on its own tile (:mod:`.walk_rough`)
===========================  ===========================================================

:mod:`.base` holds what they share: the params (``HexapodParams``), the config fields of
a body on the ground (:class:`~.base.HexapodConfig`: the contact model, spawn, fall
rule, the energy, tilt and spin weights, noise), and the base task (:class:`~.base.HexapodTask`):
the robot on the task's scene (a flat floor unless the task is given another ground,
:mod:`jaxenvs.scenes`), the spawn at a random yaw, the fall rule and the servos' energy.
Shared reward terms live in :mod:`jaxenvs.tasks.rewards`.

The robot (geometry, servos, sensors, randomisable fields) is described in
:mod:`jaxenvs.robots.hexapod`. Actions in [-1, 1] are the robot's command map: joint
POSITION targets over each joint range (0 = the standing pose): a zero action holds a
stable stance. Each task's observation is :meth:`observation` of the robot's readings
(:meth:`~jaxenvs.robots.base.Robot.sense`) and the task's own state (:meth:`task_state`).

Physics for MJX speed on CPU (measurements in benchmarks/NOTES.md): the only collisions
are six explicit foot-ground pairs (condim 3), added by the scene; joints are unlimited
(no limit rows: the servo range is the joint range); Euler integration with damping
implicit; a SPARSE mass matrix. The contact model is the config's (``cone``, ``solver``
and their iterations, :func:`~.base.contact_edit`): by default the elliptic cone, whose
friction does not depend on the robot's heading, and ``solver: auto``, which picks
Newton's method where it is fast (MuJoCo C, MJX on an accelerator) and a few CG
iterations for MJX on a CPU, so that no step there calls LAPACK (MJX's Newton solver and
dense factorisations do). ``cone: pyramidal`` with ``solver: cg`` is the model the flat
tasks had before (its friction pyramid's edges are fixed in the floor's frame). MuJoCo
does not evaluate the MJCF's sensors in the physics steps (no task reads ``sensordata``).

Params (``HexapodParams``, ``JoystickParams``): ``model`` holds MJX model fields
``body_mass``, ``body_inertia``, ``dof_damping``, ``actuator_gainprm``,
``actuator_biasprm`` and (walker and joystick) ``pair_friction``; the walker's and the
leg's ``target_range`` is the task's target range. ``sample_params`` draws ``model`` from
the config's ranges (:class:`~jaxenvs.robots.hexapod.HexapodRanges`): each body's mass and
inertia together by ``mass_scale``, each foot pair's friction by ``friction_scale``, each
servo's kp (gain and bias together) by ``gain_scale`` and each joint's damping by
``damping_scale``.
"""

from jaxenvs.tasks.hexapod.base import (
    CONES,
    SOLVERS,
    HexapodConfig,
    HexapodParams,
    HexapodRandomization,
    HexapodTask,
    contact_edit,
    contact_solver,
    solver_edit,
)
from jaxenvs.tasks.hexapod.joystick import (
    SENSOR_SIZE,
    HexapodJoystick,
    JoystickConfig,
    JoystickExtras,
    JoystickParams,
    heading,
    heading_velocity,
    low_pass,
    sample_command,
)
from jaxenvs.tasks.hexapod.one_leg import HexapodOneLeg, OneLegConfig, OneLegExtras
from jaxenvs.tasks.hexapod.rough import (
    HexapodJoystickRough,
    JoystickRoughConfig,
    TerrainFields,
    TerrainTask,
)
from jaxenvs.tasks.hexapod.walk import OBS_NOISE, TARGET, HexapodWalk, WalkConfig, WalkExtras
from jaxenvs.tasks.hexapod.walk_rough import HexapodWalkRough, WalkRoughConfig

__all__ = [
    "CONES",
    "OBS_NOISE",
    "SENSOR_SIZE",
    "SOLVERS",
    "TARGET",
    "HexapodConfig",
    "HexapodJoystick",
    "HexapodJoystickRough",
    "HexapodOneLeg",
    "HexapodParams",
    "HexapodRandomization",
    "HexapodTask",
    "HexapodWalk",
    "HexapodWalkRough",
    "JoystickConfig",
    "JoystickExtras",
    "JoystickParams",
    "JoystickRoughConfig",
    "OneLegConfig",
    "OneLegExtras",
    "TerrainFields",
    "TerrainTask",
    "WalkConfig",
    "WalkExtras",
    "WalkRoughConfig",
    "contact_edit",
    "contact_solver",
    "heading",
    "heading_velocity",
    "low_pass",
    "sample_command",
    "solver_edit",
]
