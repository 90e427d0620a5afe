"""``HexapodJoystickRough-v0``: the joystick task (:mod:`.joystick`) on a terrain of
difficulty levels x terrain types (:mod:`jaxenvs.scenes.terrain`), with a per-env level
curriculum; a blind policy and a privileged critic.

* **Ground.** The generated terrain of the config's ``levels``, ``terrain_types``,
  ``tile_size``, ``terrain_border`` and ``terrain_seed`` (the other generator settings at
  their defaults: docs/terrain.md) is the scene's ground; the six feet are paired with it.
  The terrain is generated once per process and config (:func:`terrain_of`).
* **Curriculum.** Each env's carry (:class:`RoughCarry`) holds its level and its tile's
  column (its terrain type). At :meth:`~jaxenvs.core.Env.reset` the level is drawn
  uniformly in ``min_init_level..max_init_level`` and the column among the columns of
  ``spawn_types`` (every column when empty); the column stays with the env. After each
  finished episode (:meth:`HexapodJoystickRough._carry_update`, legged_gym's rule by
  default) the level goes up by one when the body ended farther than ``promote_fraction``
  of a tile from its spawn (half a tile), else down by one when it covered less than
  ``demote_fraction`` (half) of the distance its commands asked for; an env promoted past
  the top level goes to a level drawn uniformly over all of them. With ``curriculum``
  False the level never changes (an evaluation at fixed levels).
* **Commanded distance.** The commands are redrawn during an episode (every
  ``command_interval`` steps), so the distance asked for is the length of the world-frame
  displacement the commands would have made, each step's commanded (vx, vy) turned by the
  body's heading at the step; an episode that ended early (a fall) is scaled up to the
  whole ``episode_length``, as legged_gym compares with the command times the episode's
  full length.
* **Start.** The joystick's start (a random yaw, the joints around the stance, at rest)
  moved onto the env's tile: the body ``init_height`` above the tile's origin
  (:attr:`jaxenvs.scenes.terrain.Terrain.origins`: its centre, at the highest ground of
  its flat platform).
* **Heights.** The body's height, the fall rule (``min_height``) and the ``height``
  metric are measured above the ground right below the torso's origin
  (:func:`jaxenvs.scenes.height.height`, MuJoCo's own triangulation), not above z = 0.
  The joystick's reward reads no height, unless ``low_body_weight`` > 0 (0 in the env's
  defaults): then it also loses ``low_body_weight * max(0, low_body_height - h)^2``
  for a body ``h`` above that ground, a body that sags towards the fall rule.
* **Observation.** The joystick's, unchanged (encoders, IMU, the last actions, the
  command): a blind policy that runs on a robot without a height sensor.
* **Gait prior** (``gait_frequency`` > 0; off in the env's defaults, on in the shipped PPO
  config: 2.5 Hz, a lift of 0.5, with the low-body penalty). A clock counts the control
  steps since the episode's start (:class:`RoughExtras` ``clock``, the task state's third
  entry); under a non-zero command each femur's action gets a lift in its tripod's
  half-cycle (:meth:`HexapodJoystickRough.gait_offset`) before the delay, noise and
  filter, the last actions in the observation hold the lifted ones, and the
  observation holds the phase's sine and cosine before the command (65 entries). A
  deploy loop keeps the clock and adds the lift (``with_clock``, ``prior_action``).
* **Critic.** Privileged metrics a critic may read (PPO's ``critic_info``): the joystick's
  body velocity (``vel_forward``, ``vel_lateral``, ``yaw_rate``) and ``height``, and a
  height scan, one scalar per point (``scan_00`` .. ``scan_48``): the ground minus the
  torso's height at a 7 x 7 grid 7 cm apart in the heading frame (:data:`SCAN_OFFSETS`,
  x forward, y left, x varying fastest; 0.42 m square, the feet's reach), clipped to
  +-1 m. PPO's ``critic_info`` takes scalar ``info`` entries, so the scan is 49 of them.
* **Metrics.** The joystick's, plus ``level`` (the env's level; the run loop reports its
  mean per chunk in progress.csv, the progress bar and the learning curve) and the scan.
* **Contact.** The family's elliptic friction cone (``cone``) and ``solver: auto``, the
  settings docs/terrain.md measured heading-independent and stable on the heightfield:
  Newton's method (4 iterations, 20 line-search steps) under MuJoCo C and MJX on an
  accelerator, and CG for MJX on a CPU, where MJX's Newton calls LAPACK's batched
  Cholesky, which stalls XLA's CPU thread pool; there this task converges CG further
  (``solver_iterations`` 30, ``ls_iterations`` 10) than the flat tasks, whose few
  iterations diverge on the heightfield (both solves converge to the same contact
  forces). Only the feet collide with the ground (the torso and shins pass through it; a
  body that sinks below ``min_height`` above the ground has fallen). MJX gives a sphere on
  a heightfield four contact slots, 24 for the six feet (six on the plane), and its solve
  costs with every slot; under MJX a step of this task keeps the 6 deepest
  (``max_contacts``; the walker on the terrain keeps 8). On one H200 at 65,536 and 8,192
  envs, 6 step it at 0.84x and 0.93x the flat joystick's rate, 8 at 0.76x and 0.87x, and
  8 at 1.57x and 1.40x the rate of all 24 (docs/terrain.md). MuJoCo C keeps every
  contact; policies trained with 6 track as well under it as under MJX.
* **Episode.** 400 control steps (20 s, legged_gym's episode), four commands.
"""

from __future__ import annotations

import dataclasses
import functools
import math
from collections.abc import Callable
from typing import TYPE_CHECKING, Any, ClassVar

import jax
import jax.numpy as jnp
import mujoco
from flax import struct

from jaxenvs.config import require
from jaxenvs.core import State
from jaxenvs.robots.base import Readings
from jaxenvs.scenes import HFIELD_CONTACTS, Ground, Marker, Scene
from jaxenvs.scenes.height import HeightField, height, height_scan, scan_grid
from jaxenvs.scenes.terrain import TYPES, Terrain, TerrainConfig, TerrainConfigError, generate
from jaxenvs.tasks.hexapod.base import HexapodTask
from jaxenvs.tasks.hexapod.joystick import (
    HexapodJoystick,
    JoystickConfig,
    JoystickExtras,
    JoystickParams,
    heading,
)

if TYPE_CHECKING:
    from mujoco import mjx

__all__ = [
    "SCAN_KEYS",
    "SCAN_OFFSETS",
    "HexapodJoystickRough",
    "JoystickRoughConfig",
    "RoughCarry",
    "RoughExtras",
    "TerrainFields",
    "TerrainTask",
    "terrain_of",
]

#: the critic's height scan: a 7 x 7 grid, 7 cm apart, in the body's heading frame
SCAN_OFFSETS = scan_grid(7, 7, 0.07)
#: the scan's metric keys, one per point of :data:`SCAN_OFFSETS`
SCAN_KEYS = tuple(f"scan_{i:02d}" for i in range(len(SCAN_OFFSETS)))
#: folded into a finished episode's key for the draw of a level past the top
_LEVEL_SALT = 0x6C76
#: this config's name of each generator field it sets under another name
_TERRAIN_FIELDS = {
    "types": "terrain_types",
    "border": "terrain_border",
    "seed": "terrain_seed",
    "spacing": "terrain_spacing",
    # the generator's platform is no task key; with the tile checked against it (in
    # validate_terrain), only its whole number of samples can fail: the spacing's
    "platform": "terrain_spacing",
}


@dataclasses.dataclass(frozen=True)
class TerrainFields:
    """The config fields of a hexapod task on a generated terrain with a level curriculum
    (:class:`TerrainTask`), mixed into the task's own config, listed first among its bases
    (so that its fields follow the flat task's), which calls :meth:`validate_terrain` from
    its ``validate``.

    Attributes:
      episode_length: 400 control steps (20 s), legged_gym's episode (a field of the
        task's config; the terrain tasks' default).
      solver_iterations, ls_iterations: the CG solve's (MJX on a CPU: the family's
        ``solver: auto``), 30 and 10: converged (the flat tasks' few diverge on the
        heightfield; fields of the task's config).
      max_contacts: under MJX, the 8 deepest contacts of a step are kept (of the feet's
        24 slots on the heightfield; a field of the task's config; the joystick's
        config keeps 6).
      levels: difficulty levels of the terrain (rows of tiles).
      terrain_types: the terrain type of each column of tiles
        (:data:`jaxenvs.scenes.terrain.TYPES`).
      tile_size: side of a tile (m; a multiple of the terrain's 2.5 cm spacing).
      terrain_border: the flat margin around the tiles (m): 10 m, so that from any
        tile's centre an episode at the joystick's fastest command (0.47 m/s for 20 s:
        9.4 m) ends with the feet (within 0.3 m of the body) 1.8 m inside the field (with
        a 1 m margin, robots on the outer tiles walked off the field's edge and fell).
      terrain_seed: the terrain generator's seed.
      terrain_spacing: the heightfield's sample spacing (m; the generator's 2.5 cm, about
        a foot's diameter).
      min_init_level, max_init_level: an env's first level is uniform in this range.
      spawn_types: the terrain types an env may be given (empty: every column).
      curriculum: move the levels after each episode (False: they stay as drawn).
      hfield_contact: how MuJoCo C collides the feet with the heightfield
        (:attr:`jaxenvs.scenes.Scene.hfield_contact`): ``"surface"`` (jaxenvs' collider:
        a flat cell gives one vertical contact) or ``"mujoco"`` (MuJoCo's prisms). MJX
        has its own collider either way.
    """

    episode_length: int = 400
    solver_iterations: int = 30
    ls_iterations: int = 10
    max_contacts: int = 8
    levels: int = 10
    terrain_types: tuple[str, ...] = TYPES
    tile_size: float = 3.0
    terrain_border: float = 10.0
    terrain_seed: int = 0
    terrain_spacing: float = 0.025
    min_init_level: int = 0
    max_init_level: int = 2
    spawn_types: tuple[str, ...] = ()
    curriculum: bool = True
    hfield_contact: str = "surface"

    def terrain_config(self) -> TerrainConfig:
        """The terrain generator's config (its other fields at their defaults)."""
        return TerrainConfig(
            levels=self.levels,
            types=self.terrain_types,
            tile_size=self.tile_size,
            border=self.terrain_border,
            seed=self.terrain_seed,
            spacing=self.terrain_spacing,
        )

    def validate_terrain(self) -> None:
        """A :class:`~jaxenvs.config.ConfigError` naming the first bad terrain field."""
        require(self.levels >= 1, "levels", "must be >= 1")
        unknown = sorted(set(self.terrain_types) - set(TYPES))
        require(bool(self.terrain_types) and not unknown, "terrain_types", f"unknown {unknown}")
        platform = TerrainConfig.platform
        require(
            self.tile_size > platform,
            "tile_size",
            f"must be larger than the generator's {platform:g} m platform",
        )
        try:  # what remains: the tile's size and the border against the sample spacing
            self.terrain_config()
        except TerrainConfigError as err:
            require(False, _TERRAIN_FIELDS.get(err.field, err.field), str(err))
        require(
            0 <= self.min_init_level <= self.max_init_level < self.levels,
            "max_init_level",
            f"must satisfy 0 <= min_init_level <= max_init_level < levels ({self.levels})",
        )
        foreign = sorted(set(self.spawn_types) - set(self.terrain_types))
        require(not foreign, "spawn_types", f"{foreign} not among terrain_types")
        require(
            self.hfield_contact in HFIELD_CONTACTS,
            "hfield_contact",
            f"must be one of {HFIELD_CONTACTS}",
        )


@dataclasses.dataclass(frozen=True)
class JoystickRoughConfig(TerrainFields, JoystickConfig):
    """``HexapodJoystickRough-v0`` (the joystick's fields:
    :class:`~jaxenvs.tasks.hexapod.joystick.JoystickConfig`; the terrain's:
    :class:`TerrainFields`; the module docstring says how each is used).

    Attributes:
      promote_fraction: promote when the body ended farther than this fraction of
        ``tile_size`` from its spawn ...
      demote_fraction: ... else demote when it covered less than this fraction of the
        distance its commands asked for.
      gait_frequency, gait_lift: a tripod gait prior (0 Hz: none). A phase advancing at
        ``gait_frequency`` from each episode's start; under a non-zero command each
        femur's action gets ``gait_lift * max(0, sin(2 pi (phase + g / 2)))`` added
        (``g`` 0 for lf, rm, lr and 1 for rf, lm, rr; clipped to [-1, 1]) before the
        delay, noise and filter, and the observation gets the phase's sine and cosine
        before the command.
      low_body_height, low_body_weight: a penalty on a body that sags towards the fall
        rule: ``low_body_weight * max(0, low_body_height - h)^2`` taken from the reward
        at each step, ``h`` the body's height above the ground below it (as the fall
        rule reads it; 0 weight: none).
      max_contacts: under MJX, the 6 deepest contacts of a step are kept
        (:class:`TerrainFields`' default, 8, is the walker's; docs/terrain.md says what
        a budget drops and what it costs).
    """

    max_contacts: int = 6
    promote_fraction: float = 0.5
    demote_fraction: float = 0.5
    gait_frequency: float = 0.0
    gait_lift: float = 0.38
    low_body_height: float = 0.1
    low_body_weight: float = 0.0

    nonnegative: ClassVar[tuple[str, ...]] = (
        *JoystickConfig.nonnegative,
        "demote_fraction",
        "gait_frequency",
        "gait_lift",
        "low_body_height",
        "low_body_weight",
    )

    def validate(self) -> None:
        super().validate()
        self.validate_terrain()
        require(self.promote_fraction > 0, "promote_fraction", "must be > 0")
        nyquist = 0.5 / (self.timestep * self.substeps)
        require(
            self.gait_frequency < nyquist,
            "gait_frequency",
            f"must be below half the control rate ({nyquist:g} Hz)",
        )
        require(self.gait_lift <= 2, "gait_lift", "must be <= 2 (an action's whole range)")


@functools.lru_cache(maxsize=4)
def terrain_of(config: TerrainConfig) -> Terrain:
    """The terrain of ``config`` (:func:`jaxenvs.scenes.terrain.generate`), generated once
    per process: it is read-only, so every env of one config shares it."""
    return generate(config)


class RoughCarry(struct.PyTreeNode):
    """An env's curriculum state, kept across its episodes.

    Attributes:
      level: its difficulty level (int32).
      column: its tile's column, i.e. its terrain type (int32).
    """

    level: jax.Array
    column: jax.Array


class RoughExtras(JoystickExtras):
    """The joystick's extras and what the curriculum reads of an episode.

    Attributes:
      level: the episode's level (int32; the carry's, for the ``level`` metric).
      spawn: where the body started (world x, y; m).
      commanded: the world-frame displacement the commands asked for so far (x, y; m).
      clock: control steps since the episode's start (int32; the gait prior's phase).
    """

    level: jax.Array
    spawn: jax.Array
    commanded: jax.Array
    clock: jax.Array


class TerrainTask(HexapodTask[Any]):
    """What a hexapod task on a generated terrain with a level curriculum adds to its
    flat task (a mixin listed before it: ``class T(TerrainTask, FlatTask)``): the terrain
    as the scene's ground, the curriculum's carry (:class:`RoughCarry`) and its first
    draw, the level rule's bookkeeping (:meth:`next_level`), the start moved onto the
    env's tile, heights above the ground under the body and the critic's height scan.

    The task's ``__init__`` calls :meth:`setup_terrain` with its config (a
    :class:`TerrainFields`) and passes the terrain it returns to the flat task's
    ``__init__`` as the ground; it defines ``_carry_update`` with its own promotion and
    demotion test.
    """

    #: the terrain the robot walks on (the scene's ground)
    terrain: Terrain
    #: the heightfield the height queries read
    field: HeightField

    def setup_terrain(self, config: TerrainFields) -> Terrain:
        """Generate (or reuse: :func:`terrain_of`) ``config``'s terrain and keep what the
        programs read of it: the heightfield, the tiles' origins and the columns an env
        may be given, each on the default device once (one constant of every compiled
        program, however many queries read it). Returns the terrain, the scene's ground."""
        config.validate_terrain()  # before generating: a ConfigError names the task's key
        self._terrain_fields = config
        self.terrain = terrain_of(config.terrain_config())
        self.field = HeightField(*(jnp.asarray(x) for x in self.terrain.field()))
        self._origins = jnp.asarray(self.terrain.origins)
        allowed = [
            i for i, t in enumerate(self.terrain.types) if t in (config.spawn_types or TYPES)
        ]
        self._spawn_columns = jnp.asarray(allowed, jnp.int32)
        return self.terrain

    def scene(self, config: Any, ground: Ground | None, markers: tuple[Marker, ...]) -> Scene:
        """The flat task's scene with the config's collider under MuJoCo C."""
        base = super().scene(config, ground, markers)
        return dataclasses.replace(base, hfield_contact=config.hfield_contact)

    def model_edit(self, config: Any) -> Callable[[mujoco.MjModel], None]:
        """The flat task's edit (the contact model:
        :func:`~jaxenvs.tasks.hexapod.base.contact_edit`) and a brighter headlight
        (drawing only: the scene's one light is above the world's origin, and most tiles
        are metres away)."""
        contact = super().model_edit(config)

        def edit(model: mujoco.MjModel) -> None:
            contact(model)
            model.vis.headlight.ambient[:] = 0.35
            model.vis.headlight.diffuse[:] = 0.55

        return edit

    # ------------------------------------------------------------------ curriculum
    def _carry_init(self, key: jax.Array, params: Any) -> RoughCarry:
        """A level uniform in ``min_init_level..max_init_level``, a column uniform among
        the ``spawn_types`` columns."""
        del params
        c = self._terrain_fields
        u = jax.random.uniform(key, (2,))
        span = c.max_init_level - c.min_init_level + 1
        level = c.min_init_level + jnp.minimum(jnp.floor(u[0] * span), span - 1)
        n = self._spawn_columns.shape[0]
        pick = jnp.minimum(jnp.floor(u[1] * n), n - 1).astype(jnp.int32)
        return RoughCarry(level=level.astype(jnp.int32), column=self._spawn_columns[pick])

    def next_level(
        self, carry: RoughCarry, up: jax.Array, down: jax.Array, final: State
    ) -> RoughCarry:
        """``carry`` after an episode (its last state ``final``) that earned a promotion
        (``up``) or a demotion (``down``, read only where not ``up``): the level one up or
        down, kept at 0 from below; an env promoted past the top level goes to a level
        drawn uniformly over all of them. Unchanged without ``curriculum``."""
        c = self._terrain_fields
        if not c.curriculum:
            return carry
        down = down & ~up
        level = carry.level + up.astype(jnp.int32) - down.astype(jnp.int32)
        u = jax.random.uniform(jax.random.fold_in(final.key, _LEVEL_SALT))
        anywhere = jnp.minimum(jnp.floor(u * c.levels), c.levels - 1).astype(jnp.int32)
        level = jnp.where(level >= c.levels, anywhere, jnp.maximum(level, 0))
        return carry.replace(level=level)

    def origin(self, carry: RoughCarry) -> jax.Array:
        """The world position (x, y, ground z) of the tile of ``carry``'s level and
        column: where its episodes start."""
        return self._origins[carry.level, carry.column]

    def on_tile(self, data: mjx.Data, carry: RoughCarry) -> tuple[mjx.Data, jax.Array]:
        """``data`` (a start on the flat floor at the world's origin) moved onto the env's
        tile, the body ``init_height`` above its origin, and the origin."""
        origin = self.origin(carry)
        return data.replace(qpos=data.qpos.at[:3].add(origin)), origin

    # ------------------------------------------------------------------ heights
    def ground(self, xy: jax.Array) -> jax.Array:
        """The terrain's height (m) at world points ``xy`` (``..., 2``)."""
        return height(self.field, xy)

    def height_above_ground(self, pos: jax.Array) -> jax.Array:
        """The height (m) of a body at ``pos`` above the terrain under it (the fall rule
        and the ``height`` metric read it)."""
        return pos[2] - self.ground(pos[:2])

    def scan_metrics(self, data: mjx.Data, level: jax.Array) -> dict[str, jax.Array]:
        """``level`` (float) and the height scan under the body (:data:`SCAN_KEYS`: the
        ground minus the torso's height at :data:`SCAN_OFFSETS`, clipped to +-1 m)."""
        pos = data.qpos[:3]
        scan = height_scan(self.field, pos, heading(data.qpos[3:7]), SCAN_OFFSETS)
        scan = jnp.clip(scan, -1.0, 1.0)
        return {"level": level.astype(jnp.float32)} | {k: scan[i] for i, k in enumerate(SCAN_KEYS)}

    # ------------------------------------------------------------------ for tools
    def tile_of(self, xy: Any) -> tuple[int, int]:
        """The (level, column) of the generated tile holding world point ``xy`` (host
        numbers; ``ValueError`` off the tiles)."""
        cfg = self.terrain.config
        assert cfg is not None
        x0, _, y0, _ = self.terrain.tile_bounds(0, 0)
        col = math.floor((float(xy[0]) - x0) / cfg.tile_size)
        level = math.floor((float(xy[1]) - y0) / cfg.tile_size)
        if not (0 <= level < cfg.levels and 0 <= col < len(cfg.types)):
            raise ValueError(f"({float(xy[0]):.2f}, {float(xy[1]):.2f}) is off the tiles")
        return level, col


class HexapodJoystickRough(TerrainTask, HexapodJoystick):
    """``HexapodJoystickRough-v0`` (the module docstring): the joystick on a terrain with
    a level curriculum. Observation, action, command and reward as ``HexapodJoystick-v0``;
    heights above the ground; ``level`` and the height scan among the metrics."""

    metric_keys = (*HexapodJoystick.metric_keys, "level", *SCAN_KEYS)  # type: ignore[assignment]
    #: the joystick's deploy fields and the gait prior's (the observation's layout and the
    #: action a deploy loop applies)
    deploy_fields = (*HexapodJoystick.deploy_fields, "gait_frequency", "gait_lift")
    config: JoystickRoughConfig

    def __init__(self, config: JoystickRoughConfig | None = None) -> None:
        config = config or JoystickRoughConfig()
        super().__init__(config, self.setup_terrain(config))
        #: whether the tripod gait prior is on (``gait_frequency`` > 0)
        self.gait = config.gait_frequency > 0
        if self.gait:
            self.observation_size += 2

    # ------------------------------------------------------------------ the gait prior
    def gait_phase(self, clock: jax.Array) -> jax.Array:
        """The gait prior's phase (cycles, from 0 at an episode's start) after ``clock``
        control steps."""
        return clock.astype(jnp.float32) * self.control_dt * self.config.gait_frequency

    def gait_offset(self, clock: jax.Array, command: jax.Array) -> jax.Array:
        """The gait prior's action offset (18) after ``clock`` control steps under
        ``command``: each femur's ``gait_lift * max(0, sin(2 pi (phase + g / 2)))``, ``g``
        0 for the tripod lf, rm, lr and 1 for rf, lm, rr; zero under a zero command."""
        group = jnp.asarray([0.0, 0.5, 0.0, 0.5, 0.0, 0.5])  # lf lm lr rf rm rr
        wave = jnp.sin(2.0 * math.pi * (self.gait_phase(clock) + group))
        lift = self.config.gait_lift * jnp.maximum(0.0, wave)
        lift = jnp.where(jnp.any(command != 0), lift, 0.0)
        return jnp.zeros((6, 3)).at[:, 1].set(lift).reshape(18)

    def prior_action(self, task: tuple[jax.Array, ...], action: jax.Array) -> jax.Array:
        """The action the env applies and the observation's history holds for the policy's
        ``action`` in task state ``task``: with the gait prior, ``action`` plus
        :meth:`gait_offset` at the task's clock and command, clipped to [-1, 1];
        ``action`` itself without (a deploy loop applies it to each action it sends)."""
        if not self.gait:
            return super().prior_action(task, action)
        command, _, clock = task
        return jnp.clip(action + self.gait_offset(clock, command), -1.0, 1.0)

    def with_clock(self, task: tuple[jax.Array, ...], steps: jax.Array) -> tuple[jax.Array, ...]:
        """The task state with its clock at ``steps`` control steps since the start (a
        deploy loop's step count); ``task`` itself without the gait prior."""
        if not self.gait:
            return super().with_clock(task, steps)
        return (task[0], task[1], jnp.asarray(steps, jnp.int32))

    def task_state(self, data: mjx.Data, extras: JoystickExtras) -> tuple[jax.Array, ...]:
        """The joystick's ``(command, actions)``, and with the gait prior the clock
        (control steps since the episode's start)."""
        base = super().task_state(data, extras)
        if not self.gait:
            return base
        assert isinstance(extras, RoughExtras)
        return (*base, extras.clock)

    def observation(self, readings: Readings, task: tuple[jax.Array, ...]) -> jax.Array:
        """The joystick's observation, with the gait prior the phase's sine and cosine
        before the command (``observation_size`` 65)."""
        if not self.gait:
            return super().observation(readings, task)
        command, actions, clock = task
        obs = super().observation(readings, (command, actions))
        angle = 2.0 * math.pi * self.gait_phase(clock)
        return jnp.concatenate([obs[:-3], jnp.stack([jnp.sin(angle), jnp.cos(angle)]), obs[-3:]])

    def with_task_input(
        self, task: tuple[jax.Array, ...], command: jax.Array
    ) -> tuple[jax.Array, ...]:
        """The joystick's, the clock kept."""
        return (*super().with_task_input(task[:2], command), *task[2:])

    def with_action_history(
        self, task: tuple[jax.Array, ...], actions: jax.Array
    ) -> tuple[jax.Array, ...]:
        """The joystick's, the clock kept."""
        return (*super().with_action_history(task[:2], actions), *task[2:])

    def _carry_update(self, carry: RoughCarry, final: State, params: JoystickParams) -> RoughCarry:
        """The next level by legged_gym's rule (module docstring), from the finished
        episode's last state ``final``."""
        del params
        c = self.config
        extras: RoughExtras = final.extras
        walked = jnp.linalg.norm(final.data.qpos[:2] - extras.spawn)
        # an episode that ended early is compared with its commands over a whole episode
        scale = c.episode_length / jnp.maximum(final.time, 1).astype(jnp.float32)
        asked = jnp.linalg.norm(extras.commanded) * scale
        up = walked > c.promote_fraction * c.tile_size
        down = walked < c.demote_fraction * asked
        return self.next_level(carry, up, down, final)

    def _start(
        self, key: jax.Array, params: JoystickParams, carry: RoughCarry
    ) -> tuple[mjx.Data, RoughExtras]:
        """The joystick's start moved onto the env's tile (``init_height`` above its
        origin)."""
        data, extras = self._init(key, params)
        data, origin = self.on_tile(data, carry)
        fields = {f.name: getattr(extras, f.name) for f in dataclasses.fields(extras)}
        rough = RoughExtras(
            **fields,
            level=carry.level,
            spawn=origin[:2],
            commanded=jnp.zeros(2, jnp.float32),
            clock=jnp.zeros((), jnp.int32),
        )
        return data, rough

    # ------------------------------------------------------------------ the step
    def _act(
        self,
        key: jax.Array,
        data: mjx.Data,
        extras: JoystickExtras,
        action: jax.Array,
        params: JoystickParams,
    ) -> tuple[mjx.Data, RoughExtras]:
        """The joystick's step, and the step's commanded displacement (the command in
        force, turned by the heading at the step's start) added to ``commanded``."""
        assert isinstance(extras, RoughExtras)
        yaw = heading(data.qpos[3:7])
        vx, vy = extras.command[0], extras.command[1]
        cos, sin = jnp.cos(yaw), jnp.sin(yaw)
        asked = self.control_dt * jnp.stack([cos * vx - sin * vy, sin * vx + cos * vy])
        action = self.prior_action(self.task_state(data, extras), action)
        data, new = super()._act(key, data, extras, action, params)
        assert isinstance(new, RoughExtras)
        return data, new.replace(commanded=extras.commanded + asked, clock=extras.clock + 1)

    def _reward(
        self,
        prev: mjx.Data,
        data: mjx.Data,
        action: jax.Array,
        extras: JoystickExtras,
        params: JoystickParams,
    ) -> tuple[jax.Array, dict[str, jax.Array]]:
        """The joystick's reward and metrics (its ``height`` above the ground), less the
        low-body penalty (``low_body_weight``), with ``level`` and the height scan
        (:data:`SCAN_KEYS`)."""
        assert isinstance(extras, RoughExtras)
        reward, metrics = super()._reward(prev, data, action, extras, params)
        c = self.config
        if c.low_body_weight > 0:
            sag = jnp.maximum(0.0, c.low_body_height - metrics["height"])
            reward = reward - c.low_body_weight * sag * sag
        return reward, metrics | self.scan_metrics(data, extras.level)
