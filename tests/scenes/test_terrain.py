"""The terrain generator (jaxenvs.scenes.terrain): layout, determinism, levels, origins, the
MJCF mapping and a user's own terrain."""

from __future__ import annotations

import dataclasses

import imageio.v3 as iio
import mujoco
import numpy as np
import pytest

from jaxenvs.robots.hexapod import COXA, FEMUR, LEG_RANGE, LEGS, TIP, Hexapod
from jaxenvs.scenes import Scene
from jaxenvs.scenes.terrain import (
    REACHABLE_STEP,
    TYPES,
    Terrain,
    TerrainConfig,
    TerrainConfigError,
    generate,
)

SMALL = TerrainConfig(levels=4, tile_size=1.5, platform=0.5, border=0.25, obstacle_count=20)


@pytest.fixture(scope="module")
def default() -> Terrain:
    return generate()


@pytest.fixture(scope="module")
def small() -> Terrain:
    return generate(SMALL)


def model_of(terrain: Terrain) -> mujoco.MjModel:
    """A plain world holding the terrain's MJCF snippet."""
    asset, geom = terrain.mjcf()
    xml = f"<mujoco><asset>{asset}</asset><worldbody>{geom}</worldbody></mujoco>"
    return mujoco.MjModel.from_xml_string(xml)


def mujoco_heights(m: mujoco.MjModel, geom: int = 0) -> np.ndarray:
    """The heights (m) MuJoCo puts the samples of its heightfield at (``geom`` the hfield
    geom): ``geom_z + data * elevation_z``."""
    nrow, ncol = int(m.hfield_nrow[0]), int(m.hfield_ncol[0])
    return m.geom_pos[geom, 2] + m.hfield_data.reshape(nrow, ncol) * m.hfield_size[0, 2]


def tile(t: Terrain, level: int, col: int) -> np.ndarray:
    """The samples of one tile."""
    c = t.config
    assert c is not None
    n, nb = round(c.tile_size / c.spacing), round(c.border / c.spacing)
    r0, c0 = nb + level * n, nb + col * n
    return t.heights[r0 : r0 + n, c0 : c0 + n].astype(np.float64)


def test_default_layout(default: Terrain) -> None:
    c = TerrainConfig()
    n, nb = round(c.tile_size / c.spacing), round(c.border / c.spacing)
    assert default.heights.shape == (2 * nb + c.levels * n + 1, 2 * nb + len(TYPES) * n + 1)
    assert default.heights.dtype == np.float32 and not default.heights.flags.writeable
    assert default.origins.shape == (c.levels, len(TYPES), 3)
    assert default.types == TYPES and default.levels == c.levels
    ex, ey = default.extent
    assert default.center == pytest.approx((0.0, 0.0), abs=1e-9)
    assert ex == pytest.approx(2 * c.border + len(TYPES) * c.tile_size)
    assert ey == pytest.approx(2 * c.border + c.levels * c.tile_size)
    # the border is flat at 0, and every tile's outer edge too (obstacles and stones aside)
    assert np.all(default.heights[:nb] == 0) and np.all(default.heights[:, -nb:] == 0)
    smooth = [j for j, name in enumerate(TYPES) if name not in ("obstacles", "stepping_stones")]
    for lv in range(c.levels):
        for j in smooth:
            h = tile(default, lv, j)
            assert np.abs(np.concatenate([h[0], h[:, 0]])).max() < 1e-6, (lv, TYPES[j])


def test_deterministic_from_the_seed() -> None:
    a, b = generate(SMALL), generate(SMALL)
    assert np.array_equal(a.heights, b.heights) and np.array_equal(a.origins, b.origins)
    c = generate(dataclasses.replace(SMALL, seed=1))
    assert not np.array_equal(a.heights, c.heights)


def _roughness(h: np.ndarray) -> float:
    return float(np.abs(np.diff(h, 2, axis=0)).mean() + np.abs(np.diff(h, 2, axis=1)).mean())


def test_harder_levels_are_harder(small: Terrain) -> None:
    c = SMALL
    col = {name: c.types.index(name) for name in c.types}
    per_level = {name: [tile(small, lv, j) for lv in range(c.levels)] for name, j in col.items()}
    assert all(np.all(h == 0) for h in per_level["flat"])
    measures = {
        # the steepest rise between neighbours: the slope, a riser, an obstacle's side
        "smooth_slope": [
            np.abs(np.diff(h, axis=1)).max() / c.spacing for h in per_level["smooth_slope"]
        ],
        "rough_slope": [_roughness(h) for h in per_level["rough_slope"]],
        "stairs_up": [np.abs(np.diff(h, axis=0)).max() for h in per_level["stairs_up"]],
        "stairs_down": [np.abs(np.diff(h, axis=0)).max() for h in per_level["stairs_down"]],
        "obstacles": [np.abs(h).max() for h in per_level["obstacles"]],
        "stepping_stones": [np.mean(h < 0) for h in per_level["stepping_stones"]],
    }
    for name, m in measures.items():
        assert all(b >= a - 1e-9 for a, b in zip(m, m[1:], strict=False)), (name, m)
        assert m[-1] > m[0], (name, m)
    for level in range(c.levels):
        step = c.at("step_height", level)
        assert measures["stairs_up"][level] == pytest.approx(step, abs=1e-6)
        assert measures["smooth_slope"][level] == pytest.approx(c.at("slope", level), abs=1e-6)
        assert measures["obstacles"][level] == pytest.approx(
            c.at("obstacle_height", level), abs=1e-6
        )
        # the stones' pit: as deep as the level says, every gap down to it
        stones = per_level["stepping_stones"][level]
        depth = c.at("pit_depth", level)
        assert np.all((np.abs(stones) < 1e-6) | (np.abs(stones + depth) < 1e-6)), level
        assert -stones.min() == pytest.approx(depth, abs=1e-6)
    # stairs up climb away from the platform, stairs down descend from it
    assert tile(small, 3, col["stairs_up"]).min() < 0 <= tile(small, 3, col["stairs_up"]).max()
    assert tile(small, 3, col["stairs_down"]).max() > 0


def test_hardest_step_within_the_hexapods_reach() -> None:
    """REACHABLE_STEP recomputed from the leg's kinematics and the torso's MJCF size: the
    highest the hip rises over a foot at the standing reach, less the torso's half height."""
    q1, q2 = np.meshgrid(*(np.linspace(-r, r, 1201) for r in LEG_RANGE[1:]), indexing="ij")
    reach = COXA + FEMUR * np.cos(q1) + TIP * np.sin(q1 + q2)
    tip_z = FEMUR * np.sin(q1) - TIP * np.cos(q1 + q2)
    m = mujoco.MjModel.from_xml_path(str(Hexapod.xml))
    half = m.geom_size[mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_GEOM, "torso"), 2]
    underside = -tip_z[reach >= COXA + FEMUR].min() - half
    assert underside == pytest.approx(REACHABLE_STEP, abs=2e-3)
    c = TerrainConfig()
    for name in ("step_height", "obstacle_height"):
        assert c.at(name, c.levels - 1) < REACHABLE_STEP


def test_origins_on_their_tiles(small: Terrain) -> None:
    c, f = SMALL, small
    for level in range(c.levels):
        for j in range(len(c.types)):
            x, y, z = f.origins[level, j]
            xmin, xmax, ymin, ymax = f.tile_bounds(level, j)
            assert (x, y) == pytest.approx(((xmin + xmax) / 2, (ymin + ymax) / 2), abs=1e-5)
            # the highest ground within spawn_radius of the centre
            near = _near(f, x, y, c.spawn_radius)
            assert z == pytest.approx(f.heights[near].max(), abs=1e-6)
            if f.types[j] != "rough_slope":  # a flat platform under the spawn
                assert f.heights[near].min() == pytest.approx(z, abs=1e-6)


def _near(t: Terrain, x: float, y: float, r: float) -> np.ndarray:
    """The samples within ``r`` of ``(x, y)`` along x and y (a mask of ``t.heights``)."""
    return (np.abs(_xs(t) - x) <= r + 1e-6)[None, :] & (np.abs(_ys(t) - y) <= r + 1e-6)[:, None]


def _xs(t: Terrain) -> np.ndarray:
    return t.corner[0] + np.arange(t.heights.shape[1]) * t.spacing


def _ys(t: Terrain) -> np.ndarray:
    return t.corner[1] + np.arange(t.heights.shape[0]) * t.spacing


def test_mjcf_puts_every_sample_at_its_height(small: Terrain) -> None:
    m = model_of(small)
    assert (int(m.hfield_nrow[0]), int(m.hfield_ncol[0])) == small.heights.shape
    span = float(small.heights.max() - small.heights.min())
    assert np.abs(mujoco_heights(m) - small.heights).max() < 1e-6 * max(span, 1.0)
    assert m.geom_pos[0, :2] == pytest.approx(small.center, abs=1e-9)
    assert m.geom_friction[0] == pytest.approx(small.friction)
    # the same heightfield through MjSpec (a scene's ground)
    spec = mujoco.MjSpec()
    small.add_to(spec)
    m2 = spec.compile()
    assert np.abs(mujoco_heights(m2) - mujoco_heights(m)).max() < 1e-6
    assert m2.hfield_size[0] == pytest.approx(m.hfield_size[0])


def test_a_terrain_is_a_scenes_ground(small: Terrain) -> None:
    feet = tuple(f"{leg}_foot" for leg in LEGS)
    m = Scene(robot=Hexapod.xml, ground=small, contacts=feet).spec().compile()
    ground = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_GEOM, small.name)
    assert m.nhfield == 1 and m.geom_type[ground] == mujoco.mjtGeom.mjGEOM_HFIELD
    assert m.npair == len(feet) and np.all(m.pair_geom1 == ground)
    assert np.abs(mujoco_heights(m, ground) - small.heights).max() < 1e-6


def test_from_array_round_trip() -> None:
    rng = np.random.default_rng(0)
    h = rng.uniform(-0.3, 0.5, (23, 31))
    t = Terrain.from_array(h, spacing=0.05, center=(1.0, -2.0))
    assert np.array_equal(t.heights, h.astype(np.float32))
    assert t.corner == pytest.approx((1.0 - 15 * 0.05, -2.0 - 11 * 0.05))
    assert t.origins.shape == (1, 1, 3) and t.types == ("custom",)
    assert np.abs(mujoco_heights(model_of(t)) - h).max() < 1e-6
    flat = Terrain.from_array(np.full((4, 5), 0.2), spacing=0.1)
    assert np.abs(mujoco_heights(model_of(flat)) - 0.2).max() < 1e-7


def test_from_image_round_trip(tmp_path) -> None:  # type: ignore[no-untyped-def]
    rng = np.random.default_rng(1)
    img = rng.integers(0, 65536, (20, 30), dtype=np.uint16)
    path = tmp_path / "ground.png"
    iio.imwrite(path, img)
    t = Terrain.from_image(path, spacing=0.02, height_scale=0.4, base=-0.1)
    expected = -0.1 + 0.4 * img[::-1].astype(np.float64) / 65535  # the image's top row at +y
    assert np.abs(t.heights - expected).max() < 1e-6
    assert t.extent == pytest.approx((29 * 0.02, 19 * 0.02))
    # oriented as MuJoCo reads a PNG heightfield itself
    gray = rng.integers(0, 256, (7, 9), dtype=np.uint8)
    iio.imwrite(tmp_path / "g8.png", gray)
    ours = Terrain.from_image(tmp_path / "g8.png", spacing=0.1, height_scale=1.0)
    own = mujoco.MjModel.from_xml_string(
        f'<mujoco><asset><hfield name="h" file="{tmp_path / "g8.png"}" size="1 1 1 0.1"/>'
        '</asset><worldbody><geom type="hfield" hfield="h"/></worldbody></mujoco>'
    )
    scaled = (ours.heights - ours.heights.min()) / np.ptp(ours.heights)
    assert np.abs(own.hfield_data.reshape(7, 9) - scaled).max() < 1e-6


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"tile_size": 3.01}, "tile_size"),
        ({"types": ("flat", "lava")}, "unknown"),
        ({"levels": 0}, "levels"),
        ({"platform": 3.0}, "platform"),
        ({"step_height": (0.01,)}, "step_height"),
        ({"pit_depth": 0.2}, "pit_depth"),
        ({"pit_depth": (0.0, 0.08)}, "pit_depth"),
    ],
)
def test_bad_config_is_one_clear_error(kwargs: dict, message: str) -> None:
    with pytest.raises(ValueError, match=message):
        TerrainConfig(**kwargs)


def test_the_spawn_height_reads_the_ground_within_the_radius_only() -> None:
    # 5-cm stairs: the tile's centre lands where float noise once took in the riser 0.3 m
    # away (a sample past the 0.25 m radius), spawning the body 8 cm high at level 1
    c = TerrainConfig(
        levels=2, types=("stairs_up",), spacing=0.05, tile_size=2.0, platform=0.5,
        border=0.2, step_width=0.05, spawn_radius=0.25,
    )  # fmt: skip
    t = generate(c)
    for level in range(c.levels):
        x, y, z = t.origins[level, 0]
        assert z == pytest.approx(t.heights[_near(t, x, y, c.spawn_radius)].max(), abs=1e-6)


def test_a_spawn_radius_past_the_tile_sees_its_neighbours() -> None:
    # the origins are taken once every tile is drawn, not while later tiles are still 0
    c = TerrainConfig(
        levels=2, types=("flat", "obstacles"), tile_size=1.0, platform=0.5, border=0.25,
        spawn_radius=0.6, obstacle_height=(0.05, 0.1), obstacle_count=20,
    )  # fmt: skip
    t = generate(c)
    for level in range(c.levels):
        for j in range(len(c.types)):
            x, y, z = t.origins[level, j]
            assert z == pytest.approx(t.heights[_near(t, x, y, c.spawn_radius)].max(), abs=1e-6)


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"seed": -1}, "seed"),
        ({"levels": 2.5}, "levels"),
        ({"obstacle_count": 3.5}, "obstacle_count"),
        ({"types": "flat"}, "types"),
    ],
)
def test_integers_and_the_seed_are_checked(kwargs: dict, message: str) -> None:
    with pytest.raises(TerrainConfigError, match=message):
        TerrainConfig(**kwargs)


def test_types_and_numpy_scalars_are_normalised() -> None:
    given = TerrainConfig(types=["flat", "stairs_up"], levels=np.int64(2), base=np.float64(0.2))
    assert given.types == ("flat", "stairs_up") and hash(given) == hash(
        TerrainConfig(types=("flat", "stairs_up"), levels=2, base=0.2)
    )
    small = dataclasses.replace(given, tile_size=1.0, platform=0.5, border=0.25)
    assert model_of(generate(small)).hfield_size[0, 3] == pytest.approx(0.2)  # MJCF parses


def test_a_pair_given_as_a_list_or_an_array_is_kept_as_a_tuple() -> None:
    given = TerrainConfig(slope=[0.0, 0.3], pit_depth=np.array([0.02, 0.1]))
    assert given == TerrainConfig(slope=(0.0, 0.3), pit_depth=(0.02, 0.1))
    assert hash(given) == hash(TerrainConfig(slope=(0.0, 0.3), pit_depth=(0.02, 0.1)))
    with pytest.raises(TerrainConfigError, match="pit_depth"):
        TerrainConfig(pit_depth=("a", "b"))


def test_bad_user_terrain_is_one_clear_error() -> None:
    with pytest.raises(ValueError, match="2-D"):
        Terrain.from_array(np.zeros(5), spacing=0.1)
    with pytest.raises(ValueError, match="spacing"):
        Terrain.from_array(np.zeros((3, 3)), spacing=0.0)
    with pytest.raises(ValueError, match="finite"):
        Terrain.from_array(np.full((3, 3), np.nan), spacing=0.1)
    with pytest.raises(ValueError, match="off the terrain"):
        Terrain.from_array(np.zeros((3, 3)), spacing=0.1, origin=(5.0, 5.0))
