"""``HexapodWalkRough-v0``: the walker (:mod:`.walk`) on the rough joystick's terrain
(:mod:`.rough`: levels x terrain types of tiles), with a per-env level curriculum and its
targets on its own tile.

* **Ground, curriculum's carry, start, heights, critic's scan.** As
  ``HexapodJoystickRough-v0`` (:class:`~.rough.TerrainTask`): each env keeps its level
  and its tile's column across episodes, starts on its tile's platform, and its height,
  fall rule and observed height are measured above the ground under the body; ``level``
  and the 7 x 7 height scan (``scan_00`` .. ``scan_48``) are among the metrics, for a
  critic that may read them.
* **Targets on the tile.** Every target (the first, and each waypoint) is drawn at a
  distance in ``target_distance`` (0.75 to 1.5 m) from the tile's centre, in a uniformly
  random direction, or at the opposite point when that is farther from the body (so a
  new target is never where the body already is). With 3 m tiles every target lies on
  the env's tile, and the walk between targets keeps to it but for its edge (a body
  within ``waypoint_radius`` of a target on the edge, its feet 0.3 m around it, can
  stand just past it): the tile's level and terrain type are what the episode is
  measured on.
* **Level rule.** After each finished episode the level goes up by one when the episode
  reached at least ``promote_targets`` targets (4: about 5.6 m of walking in 20 s), else
  down by one when it reached fewer than ``demote_targets`` (2); an env promoted past the
  top level goes to a level drawn uniformly over all of them.
* **Observation, action, reward.** The walker's (49 entries, the height above the ground
  under the body); its progress, energy, tilt and spin terms.
* **Contact and episode.** The rough joystick's: the family's elliptic cone and
  ``solver: auto`` with CG converged to 30 / 10 for MJX on a CPU, MJX keeping the 8
  deepest contacts; 400 control steps (20 s).
"""

from __future__ import annotations

import dataclasses
from typing import TYPE_CHECKING, ClassVar

import jax
import jax.numpy as jnp

from jaxenvs.config import require
from jaxenvs.core import State
from jaxenvs.randomize import Range
from jaxenvs.tasks.hexapod.base import HexapodParams
from jaxenvs.tasks.hexapod.rough import SCAN_KEYS, RoughCarry, TerrainFields, TerrainTask
from jaxenvs.tasks.hexapod.walk import HexapodWalk, WalkConfig, WalkExtras, target_offset

if TYPE_CHECKING:
    from mujoco import mjx

__all__ = ["HexapodWalkRough", "WalkRoughConfig", "WalkRoughExtras"]

#: a target marker's height above the ground under it (m; drawing only)
_MARKER_LIFT = 0.01


@dataclasses.dataclass(frozen=True)
class WalkRoughConfig(TerrainFields, WalkConfig):
    """``HexapodWalkRough-v0`` (the walker's fields:
    :class:`~jaxenvs.tasks.hexapod.walk.WalkConfig`; the terrain's:
    :class:`~jaxenvs.tasks.hexapod.rough.TerrainFields`; the module docstring says how each
    is used).

    Attributes:
      target_distance: each target's distance from the tile's centre (m); the far end
        at most half a tile, so that targets lie on the tile.
      waypoint_radius: the walker's (0.25 m); must be > 0 here, since the level rule
        counts the targets reached.
      promote_targets: promote after an episode that reached at least this many targets
        ...
      demote_targets: ... else demote after one that reached fewer than this many.
    """

    target_distance: Range = (0.75, 1.5)
    promote_targets: int = 4
    demote_targets: int = 2

    nonnegative: ClassVar[tuple[str, ...]] = (*WalkConfig.nonnegative, "demote_targets")

    def validate(self) -> None:
        super().validate()
        self.validate_terrain()
        require(self.waypoint_radius > 0, "waypoint_radius", "must be > 0: levels move by targets")
        require(self.promote_targets >= 1, "promote_targets", "must be >= 1")
        require(
            self.demote_targets <= self.promote_targets,
            "demote_targets",
            f"must be <= promote_targets ({self.promote_targets})",
        )
        require(
            self.target_distance[1] <= self.tile_size / 2,
            "target_distance",
            f"must end within half a tile ({self.tile_size / 2} m): targets lie on the tile",
        )


class WalkRoughExtras(WalkExtras):
    """The walker's extras and the episode's tile.

    Attributes:
      level: the episode's level (int32; the carry's, for the ``level`` metric).
      spawn: the tile's centre, where the body started and about which targets are
        drawn (world x, y; m).
    """

    level: jax.Array
    spawn: jax.Array


class HexapodWalkRough(TerrainTask, HexapodWalk):
    """``HexapodWalkRough-v0`` (the module docstring): the walker on a terrain with a level
    curriculum, its targets on its tile. Observation, action and reward as
    ``HexapodWalk-v0``; heights above the ground; ``level`` and the height scan among the
    metrics."""

    metric_keys = (*HexapodWalk.metric_keys, "level", *SCAN_KEYS)  # type: ignore[assignment]
    config: WalkRoughConfig

    def __init__(self, config: WalkRoughConfig | None = None) -> None:
        config = config or WalkRoughConfig()
        super().__init__(config, self.setup_terrain(config))

    def _carry_update(self, carry: RoughCarry, final: State, params: HexapodParams) -> RoughCarry:
        """Up after ``promote_targets`` targets, else down below ``demote_targets``."""
        del params
        c = self.config
        reached = final.extras.targets_reached
        return self.next_level(
            carry, reached >= c.promote_targets, reached < c.demote_targets, final
        )

    def _start(
        self, key: jax.Array, params: HexapodParams, carry: RoughCarry
    ) -> tuple[mjx.Data, WalkRoughExtras]:
        """The walker's start moved onto the env's tile: the body ``init_height`` above
        its origin, the first target drawn about its centre."""
        data, extras = self._init(key, params)
        data, origin = self.on_tile(data, carry)
        target = origin[:2] + data.mocap_pos[0, :2]  # the walker drew it about (0, 0)
        data = data.replace(mocap_pos=self.place_target(data.mocap_pos, target))
        rough = WalkRoughExtras(
            targets_reached=extras.targets_reached, level=carry.level, spawn=origin[:2]
        )
        return data, rough

    def place_target(self, mocap_pos: jax.Array, target: jax.Array) -> jax.Array:
        """``mocap_pos`` with the target marker at world (x, y) ``target``, on the ground."""
        z = self.ground(target) + _MARKER_LIFT
        return mocap_pos.at[0].set(jnp.concatenate([target, z[None]]))

    def draw_target(
        self, key: jax.Array, pos: jax.Array, extras: WalkExtras, params: HexapodParams
    ) -> jax.Array:
        """A new target about the tile's centre (module docstring): at a distance in
        ``target_range`` from it in a uniformly random direction, or the opposite point
        when that is farther from the body at ``pos``."""
        assert isinstance(extras, WalkRoughExtras)
        offset = target_offset(jax.random.uniform(key, (2,)), params.target_range)
        ahead, behind = extras.spawn + offset, extras.spawn - offset
        farther = jnp.linalg.norm(ahead - pos) >= jnp.linalg.norm(behind - pos)
        return jnp.where(farther, ahead, behind)

    def _reward(
        self,
        prev: mjx.Data,
        data: mjx.Data,
        action: jax.Array,
        extras: WalkExtras,
        params: HexapodParams,
    ) -> tuple[jax.Array, dict[str, jax.Array]]:
        """The walker's reward and metrics, with ``level`` and the height scan."""
        assert isinstance(extras, WalkRoughExtras)
        reward, metrics = super()._reward(prev, data, action, extras, params)
        return reward, metrics | self.scan_metrics(data, extras.level)
