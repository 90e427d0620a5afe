"""What the hexapod tasks share: their params, the config fields of a body on the ground,
the contact model (friction cone and solver, picked per engine), and the base task (robot,
scene, spawn, fall rule, energy)."""

from __future__ import annotations

import dataclasses
import math
from typing import TYPE_CHECKING, Any, ClassVar, Generic, TypeVar

import jax
import jax.numpy as jnp
import mujoco
from flax import struct

from jaxenvs.config import require
from jaxenvs.core import Env, TaskConfig
from jaxenvs.physics import resolve_engine
from jaxenvs.robots.base import Readings, RobotTask
from jaxenvs.robots.hexapod import Hexapod, HexapodRanges
from jaxenvs.scenes import Ground, Marker, Scene
from jaxenvs.tasks import rewards

if TYPE_CHECKING:
    from collections.abc import Callable

    from mujoco import mjx


#: the walker's target: a red disc on the ground (a mocap body the task moves). Every
#: hexapod scene holds it, first among the bodies (the joystick's stays where it is drawn):
#: the randomised bodies' draws are indexed by body, so the shipped figures' draws stay
TARGET = Marker("target", pos=(1.0, 0.0, 0.01), radius=0.05, half_height=0.005)
#: the friction cones a hexapod config may name
CONES = {"pyramidal": mujoco.mjtCone.mjCONE_PYRAMIDAL, "elliptic": mujoco.mjtCone.mjCONE_ELLIPTIC}
#: the contact solvers a hexapod config may name (``"auto"``: :func:`contact_solver`)
SOLVERS = ("cg", "newton", "auto")


class HexapodParams(struct.PyTreeNode):
    """Randomisable physics and task quantities.

    Attributes:
      model: MJX model fields swapped in at every step.
      target_range: (low, high) of each target's distance from the body where it is
        drawn (walker, m: at reset and at each waypoint) or of the target posture's joint
        angles as fractions of each joint's half-range (one leg).
    """

    model: dict[str, jax.Array]
    target_range: jax.Array


@dataclasses.dataclass(frozen=True)
class HexapodRandomization(HexapodRanges, TaskConfig):
    """Fields every hexapod config has: the robot's randomisation ranges
    (:class:`~jaxenvs.robots.hexapod.HexapodRanges`: ``mass_scale``, ``friction_scale``,
    ``gain_scale``, ``damping_scale``) and the physics timing.

    Attributes:
      timestep, substeps: physics; the control period is their product (0.05 s, what
        hobby servos sustain).
    """

    timestep: float = 0.01
    substeps: int = 5


@dataclasses.dataclass(frozen=True)
class HexapodConfig(HexapodRandomization):
    """Fields of the tasks whose hexapod stands on the ground (the walker, the joystick).

    Attributes:
      episode_length: 1000 steps of 0.05 s (50 s).
      cone: the friction cone, ``"elliptic"`` (heading-independent; the default) or
        ``"pyramidal"`` (its edges fixed in the world's frame: the physics depends on the
        robot's heading).
      solver: the contact solver, ``"cg"``, ``"newton"`` or ``"auto"`` (the default:
        Newton, but CG for MJX on a CPU: :func:`contact_solver`).
      solver_iterations, ls_iterations: the CG solve's iterations and line-search steps.
      newton_iterations, newton_ls_iterations: Newton's (4 and 20 converge on the
        hexapod's contacts; with 6 line-search steps MuJoCo C's solve stopped short on
        some randomised robots).
      max_contacts: under MJX, the most contacts a step keeps, the deepest (0: all of
        the feet's contact slots, one a foot on a plane, four on a heightfield; MuJoCo C
        keeps every contact): ``jaxenvs.scenes.Scene.max_contacts``.
      energy_weight: weight of the servos' mechanical power, sum |torque x joint speed| (W).
      alive_bonus: reward per step while not fallen.
      tilt_weight: weight of the tilt penalty ``1 - up_z`` (0 upright, 0.29 at 45 degrees),
        with ``up_z`` the vertical component of the body's up axis.
      spin_weight: weight of the penalty on the body's squared roll and pitch rates
        (rad^2/s^2, body frame); yaw (turning) is free.
      min_height: the episode ends when the body's height falls below this (m) ...
      min_upright: ... or when its up axis' vertical component falls below this (0.7:
        tilted more than ~45 degrees; 0 would be lying on its side).
      init_joint_noise: initial joint angles uniform in +- this (rad) around the stance.
      init_height: initial body height (m): the feet start just above the floor.
      action_noise: std of Gaussian noise added to each action before it is clipped to
        [-1, 1] (fractions of the joint's half-range; 0: none).
      obs_noise: std of Gaussian observation noise as a multiple of the task's per-entry
        sensor scales (0: none). Both draw from the hooks' keys.
    """

    episode_length: int = 1000
    cone: str = "elliptic"
    solver: str = "auto"
    solver_iterations: int = 6
    ls_iterations: int = 3
    newton_iterations: int = 4
    newton_ls_iterations: int = 20
    max_contacts: int = 0
    energy_weight: float = 0.002
    alive_bonus: float = 0.05
    tilt_weight: float = 0.0
    spin_weight: float = 0.0
    min_height: float = 0.06
    min_upright: float = 0.7
    init_joint_noise: float = 0.05
    init_height: float = 0.14
    action_noise: float = 0.0
    obs_noise: float = 0.0

    #: the fields that must not be negative (a subclass adds its own)
    nonnegative: ClassVar[tuple[str, ...]] = (
        "energy_weight",
        "alive_bonus",
        "tilt_weight",
        "spin_weight",
        "init_joint_noise",
        "action_noise",
        "obs_noise",
    )

    def validate(self) -> None:
        super().validate()
        require(self.cone in CONES, "cone", f"must be one of {', '.join(CONES)}")
        require(self.solver in SOLVERS, "solver", f"must be one of {', '.join(SOLVERS)}")
        steps = ("solver_iterations", "ls_iterations", "newton_iterations", "newton_ls_iterations")
        for name in steps:
            require(getattr(self, name) >= 1, name, "must be >= 1")
        for name in self.nonnegative:
            require(getattr(self, name) >= 0, name, "must be >= 0")
        require(0 < self.min_height < self.init_height, "min_height", "must be in (0, init_height)")
        require(-1 <= self.min_upright < 1, "min_upright", "must be in [-1, 1)")
        require(self.max_contacts >= 0, "max_contacts", "must be >= 0 (0: no limit)")


def contact_solver(solver: str, physics: str, backend: str | None = None) -> str:
    """The solver ``solver`` means for an env stepped by ``physics`` (``"mjx"`` or ``"c"``)
    on ``backend`` (default: JAX's): itself, or for ``"auto"`` ``"newton"``, but ``"cg"``
    for MJX on a CPU (MJX's Newton calls LAPACK's batched Cholesky there, which stalls
    XLA's CPU thread pool at batches of 128 or more: benchmarks/NOTES.md)."""
    if solver != "auto":
        return solver
    on_cpu = (backend or jax.default_backend()) == "cpu"
    return "cg" if physics == "mjx" and on_cpu else "newton"


def contact_edit(config: HexapodConfig, physics: str) -> Callable[[mujoco.MjModel], None]:
    """A model edit setting the config's friction cone and contact solve for an env
    stepped by ``physics``: the solver :func:`contact_solver` picks, with its iterations
    and line-search steps."""
    cone = CONES[config.cone]
    if contact_solver(config.solver, physics) == "newton":
        kind = mujoco.mjtSolver.mjSOL_NEWTON
        solve = solver_edit(config.newton_iterations, config.newton_ls_iterations)
    else:
        kind = mujoco.mjtSolver.mjSOL_CG
        solve = solver_edit(config.solver_iterations, config.ls_iterations)

    def edit(model: mujoco.MjModel) -> None:
        solve(model)
        model.opt.solver = kind
        model.opt.cone = cone

    return edit


def solver_edit(iterations: int, ls_iterations: int) -> Callable[[mujoco.MjModel], None]:
    """A model edit setting the contact solver's iterations and line-search steps."""

    def edit(model: mujoco.MjModel) -> None:
        model.opt.iterations = iterations
        model.opt.ls_iterations = ls_iterations

    return edit


ConfigT = TypeVar("ConfigT", bound=HexapodConfig)


class HexapodTask(RobotTask, Env[ConfigT], Generic[ConfigT]):
    """The base of the tasks whose hexapod stands on its ground: the robot on the task's
    scene (:meth:`Hexapod.scene`: a flat floor unless the task names another ground, plus
    its markers, :data:`TARGET` by default), the config's solver, a spawn at a random
    yaw, the fall rule and the servos' energy.

    A subclass sets ``self._params`` after ``super().__init__`` and defines the task's
    observation, action and reward hooks.
    """

    #: the servos' forces (the energy term); every other reading comes from qpos/qvel
    derived_fields: tuple[str, ...] | None = ("actuator_force",)
    #: the test battery's vmap-vs-single tolerance: the 6-iteration CG contact solve
    #: amplifies the batched program's last-bit differences.
    vmap_atol = 1e-2
    action_size = 18
    robot: Hexapod

    def __init__(
        self,
        config: ConfigT,
        ground: Ground | None = None,
        markers: tuple[Marker, ...] = (TARGET,),
    ) -> None:
        self.robot = Hexapod()
        sim = self.robot.make_sim(
            config.timestep,
            config.substeps,
            edit=self.model_edit(config),
            scene=self.scene(config, ground, markers),
        )
        super().__init__(config, sim)

    def scene(self, config: ConfigT, ground: Ground | None, markers: tuple[Marker, ...]) -> Scene:
        """The robot on ``ground`` with ``markers`` and the config's MJX contact budget (a
        task with more to say of its scene extends it)."""
        return self.robot.scene(ground, markers, config.max_contacts)

    def model_edit(self, config: ConfigT) -> Callable[[mujoco.MjModel], None]:
        """The edit of the host model: the config's contact model (:func:`contact_edit`)
        for the engine its ``physics`` names (a task that edits more extends it)."""
        auto = config.solver == "auto"  # only then does the engine matter
        physics = resolve_engine(type(self), config.physics) if auto else config.physics
        return contact_edit(config, physics)

    def spawn(self, u: jax.Array) -> jax.Array:
        """The start's ``qpos`` from 19 uniforms in [0, 1): the body at ``init_height``
        with a yaw uniform in [-pi, pi) (``u[0]``), the joints uniform in
        +-``init_joint_noise`` around the stance (``u[1:19]``)."""
        c = self.config
        yaw = math.pi * (2.0 * u[0] - 1.0)
        quat = jnp.stack([jnp.cos(yaw / 2), 0.0, 0.0, jnp.sin(yaw / 2)])
        joints = c.init_joint_noise * (2.0 * u[1:19] - 1.0)
        return self.robot.qpos(jnp.array([0.0, 0.0, c.init_height]), quat, joints)

    def energy(self, data: mjx.Data, readings: Readings) -> jax.Array:
        """The servos' mechanical power during the step that ended in ``data`` (W)."""
        return rewards.servo_power(data.actuator_force, self.robot.joint_vel(readings))

    def height_above_ground(self, pos: jax.Array) -> jax.Array:
        """The height (m) of a body at world position ``pos`` (3,) above the ground under
        it: ``pos[2]`` on the flat floor (a task on other ground overrides it)."""
        return pos[2]

    def fallen(self, readings: Readings) -> jax.Array:
        """The body below ``min_height`` above the ground or tilted past
        ``min_upright``."""
        c = self.config
        above = self.height_above_ground(readings["torso_pos"])
        return (above < c.min_height) | (self.robot.upright(readings) < c.min_upright)

    def _terminated(self, data: mjx.Data, extras: Any, params: Any) -> jax.Array:
        """Fallen (:meth:`fallen`)."""
        return self.fallen(self.robot.sense(data))
