"""HexapodWalkRough-v0: the walker on the rough joystick's terrain: its targets on its own
tile, its level rule (targets reached), its observed height above the ground, and its
config's checks. (The terrain, the carry's first draw, the spawn and the fall rule are the
rough joystick's, tested in tests/tasks/test_hexapod_rough.py; the public battery runs on
this id in tests/tasks/test_battery.py.)

The tests use the rough joystick's small terrain (4 levels of flat ground, stairs up and
stairs down) under MuJoCo C."""

from __future__ import annotations

from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import jaxenvs
from jaxenvs.config import ConfigError
from jaxenvs.core import BatchedEnv
from jaxenvs.tasks.hexapod.rough import SCAN_KEYS, RoughCarry, TerrainTask
from jaxenvs.tasks.hexapod.walk_rough import HexapodWalkRough, WalkRoughConfig

ID = "HexapodWalkRough-v0"
SMALL = {"levels": 4, "terrain_types": ("flat", "stairs_up", "stairs_down")}
FLAT, PIT, SUMMIT = 0, 1, 2  # the small terrain's columns
TOP = 3


@pytest.fixture(scope="module")
def env() -> HexapodWalkRough:
    made = jaxenvs.make(ID, physics="c", **SMALL)
    assert isinstance(made, HexapodWalkRough) and isinstance(made, TerrainTask)
    return made


@pytest.fixture(scope="module")
def starts(env: HexapodWalkRough) -> Any:
    """A jitted batch of fresh starts on given tiles."""
    fresh = jax.jit(BatchedEnv(env, 1, devices=1).fresh_starts)

    def make(levels: Any, columns: Any, seed: int = 0) -> Any:
        levels, columns = np.broadcast_arrays(np.asarray(levels), np.asarray(columns))
        carry = RoughCarry(
            level=jnp.asarray(levels, jnp.int32), column=jnp.asarray(columns, jnp.int32)
        )
        return fresh(jax.random.split(jax.random.key(seed), levels.size), None, carry)

    return make


def test_the_first_target_is_on_the_tile_on_the_ground(env, starts) -> None:
    """The first target lies 0.75-1.5 m from the tile's centre (where the body starts),
    inside the tile, the marker 1 cm above the ground there; the metrics carry the
    level and the scan."""
    s = starts(np.repeat([0, TOP], 30), np.tile([FLAT, PIT, SUMMIT], 20))
    target = np.asarray(s.data.mocap_pos[:, 0])
    spawn = np.asarray(s.extras.spawn)
    np.testing.assert_allclose(np.asarray(s.data.qpos[:, :2]), spawn, atol=1e-6)
    dist = np.linalg.norm(target[:, :2] - spawn, axis=1)
    assert dist.min() >= 0.75 - 1e-5 and dist.max() <= 1.5 + 1e-5
    for i in range(len(target)):
        assert env.tile_of(target[i, :2]) == env.tile_of(spawn[i])
    ground = np.asarray(jax.jit(env.ground)(jnp.asarray(target[:, :2])))
    np.testing.assert_allclose(target[:, 2], ground + 0.01, atol=1e-6)
    assert {"level", "targets_reached", *SCAN_KEYS} <= set(env.metric_keys)


def test_a_waypoint_is_drawn_about_the_tile_away_from_the_body(env, starts) -> None:
    """A body that reaches its target gets a new one about the tile's centre, never
    within reach of where the body stands (the far one of a pair of opposite points),
    and the arrival is counted; a body that has not reached it keeps it."""
    s = starts(np.full(64, 2), np.arange(64) % 3, seed=5)
    target = s.data.mocap_pos[:, 0]
    qpos = s.data.qpos.at[:, :2].set(target[:, :2])  # every body on its target
    arrived = s.data.replace(qpos=qpos)
    keys = jax.random.split(jax.random.key(9), 64)
    params = jax.tree.map(lambda x: jnp.broadcast_to(x, (64, *x.shape)), env.default_params)
    draw = jax.jit(jax.vmap(env.next_target))
    data, extras = draw(keys, arrived, s.extras, params)
    new = np.asarray(data.mocap_pos[:, 0, :2])
    spawn = np.asarray(s.extras.spawn)
    dist = np.linalg.norm(new - spawn, axis=1)
    assert dist.min() >= 0.75 - 1e-5 and dist.max() <= 1.5 + 1e-5
    # the body stands 0.75-1.5 m from the centre; the far point of the pair is at least
    # the new target's distance from the centre away from it
    assert np.linalg.norm(new - np.asarray(target[:, :2]), axis=1).min() >= 0.75 - 1e-5
    np.testing.assert_array_equal(np.asarray(extras.targets_reached), 1)
    kept, extras = draw(keys, s.data, s.extras, params)  # no body on its target
    np.testing.assert_array_equal(np.asarray(kept.mocap_pos), np.asarray(s.data.mocap_pos))
    np.testing.assert_array_equal(np.asarray(extras.targets_reached), 0)


#: (level, targets reached, the next level) with the defaults (up at 4 or more, down
#: below 2)
RULE_CASES = [(1, 4, 2), (1, 9, 2), (1, 3, 1), (1, 2, 1), (1, 1, 0), (0, 0, 0), (2, 0, 1)]


def test_levels_move_by_the_targets_reached(env, starts) -> None:
    level, reached, want = (np.asarray(x) for x in zip(*RULE_CASES, strict=True))
    final = starts(level, np.arange(len(level)) % 3)
    final = final.replace(
        extras=final.extras.replace(targets_reached=jnp.asarray(reached, jnp.int32))
    )
    nxt = jax.jit(jax.vmap(env.next_carry))(final)
    np.testing.assert_array_equal(np.asarray(nxt.level), want)
    np.testing.assert_array_equal(np.asarray(nxt.column), np.asarray(final.carry.column))


def test_the_observed_height_is_above_the_ground(env, starts) -> None:
    """The observation's height entry (index 36) is the body's height above the ground
    under it: the same in the pit and on the summit of the top level's stairs, 0.56 m
    below and above z = 0."""
    s = starts([TOP, TOP, 0], [PIT, SUMMIT, FLAT])
    z = np.asarray(s.data.qpos[:, 2])
    assert z[0] < -0.3 and z[1] > 0.6
    np.testing.assert_allclose(np.asarray(s.obs[:, 36]), env.config.init_height, atol=1e-5)


@pytest.mark.parametrize(
    "field, value",
    [
        ("target_distance", (0.75, 1.6)),
        ("demote_targets", 5),
        ("promote_targets", 0),
        ("waypoint_radius", 0.0),
        ("max_init_level", 4),
        ("terrain_types", ("flat", "moon")),
    ],
)
def test_bad_config_is_named(field, value) -> None:
    config = WalkRoughConfig(**{**SMALL, field: value})
    with pytest.raises(ConfigError, match=field):
        config.validate()
