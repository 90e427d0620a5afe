"""A terrain over a heightfield: a grid of difficulty levels x terrain types, or a user's own.

:func:`generate` lays out square tiles, one row of tiles per difficulty level (level 0 the
easiest, along +y) and one column per terrain type (along +x), inside a flat border. Each
tile is a shape with a flat square platform at its centre, where an env of that level and
type is spawned (:attr:`Terrain.origins`), and every tile's outer edge at height 0, so that
neighbouring tiles meet without a cliff (obstacles and stepping stones aside). Types
(:data:`TYPES`):

* ``flat``: height 0.
* ``smooth_slope``: a square pyramid of slope ``slope`` rising from the edge to the
  platform (a hill) or falling to it (a bowl), the sign drawn per tile.
* ``rough_slope``: the same plus uniform noise of half-amplitude ``roughness`` on a
  lattice of ``rough_cell``, interpolated, fading out over the last cell before the edge;
  the noise covers the platform too (its only tile whose platform is not flat).
* ``stairs_up``: concentric steps of ``step_height`` and tread ``step_width`` rising from
  the platform (a pit) to the edge: walking out of the centre climbs.
* ``stairs_down``: the same descending from the platform (a summit) to the edge.
* ``obstacles``: ``obstacle_count`` rectangles of sides in ``obstacle_size``, each raised or
  sunk by one of ``+-obstacle_height``, ``+-obstacle_height / 2``; platform kept flat.
* ``stepping_stones``: square stones of side ``stone_size`` at height 0, ``stone_gap``
  apart (each row shifted at random) over a pit ``pit_depth`` deep.

A level's difficulty is ``d = level / (levels - 1)`` (0 at level 0, 1 at the top); each
level-dependent field is an ``(easiest, hardest)`` pair and its value at a level is
``easiest + d * (hardest - easiest)`` (:meth:`TerrainConfig.at`).

Scaled to the hexapod (jaxenvs/robots/hexapod: coxa 4 cm, femur 8 cm, foot tip 13.2 cm
below the knee, joints +-1.57 rad, a 24 x 16 x 5 cm torso whose centre stands 0.135 m up,
feet of radius 1.2 cm). With a foot at the standing reach (0.12 m from the hip axis) a tip
reaches 0.196 m above the hip, and the hip rises at most 0.196 m above the feet, putting
the torso's underside at 0.171 m: :data:`REACHABLE_STEP`, the tallest riser the body can
pass over, is the hardest step the legs can physically reach. The defaults keep every level
below it: steps 0.01 to 0.08 m (0.08 is 0.7 of the standing torso's 0.11 m clearance),
obstacles to 0.06 m, slopes to 0.4 (22 degrees), roughness to +-2 cm, stones from 40 down
to 12 cm with 2 to 6 cm gaps over a pit as deep as the level's stair riser (1 to 8 cm); 3 m
tiles sampled every 2.5 cm, about a foot's diameter (docs/terrain.md says why the pit is
no deeper than the stairs' riser).

A user's own ground: :meth:`Terrain.from_array` or :meth:`Terrain.from_image`.
:meth:`Terrain.mjcf` and :meth:`Terrain.add_to` give MuJoCo the heightfield;
:meth:`Terrain.field` the arrays :mod:`jaxenvs.scenes.height` reads.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any, NamedTuple

import mujoco
import numpy as np

from jaxenvs.scenes.height import HeightField

__all__ = [
    "FRICTION",
    "REACHABLE_STEP",
    "TYPES",
    "Mjcf",
    "Terrain",
    "TerrainConfig",
    "TerrainConfigError",
    "generate",
]

#: the terrain types, in the default order of the columns
TYPES = tuple(
    "flat smooth_slope rough_slope stairs_up stairs_down obstacles stepping_stones".split()
)
#: the tallest step the hexapod's body can pass over (m): the torso's underside with the
#: hip at its highest over feet at the standing reach (module docstring)
REACHABLE_STEP = 0.171
#: the ground's sliding, torsional and rolling friction (the hexapod's floor's)
FRICTION = (1.0, 0.005, 0.0001)

Pair = tuple[float, float]
_LEVELLED = (
    "slope",
    "roughness",
    "step_height",
    "obstacle_height",
    "stone_size",
    "stone_gap",
    "pit_depth",
)


@dataclasses.dataclass(frozen=True)
class TerrainConfig:
    """The generated terrain (module docstring). Lengths in metres.

    Attributes:
      levels: rows of tiles, one per difficulty level.
      types: the terrain type of each column of tiles (names from :data:`TYPES`; a name may
        repeat to give a type more columns).
      tile_size: side of a square tile.
      spacing: distance between heightfield samples (a multiple of it must make
        ``tile_size``, ``border`` and ``platform``).
      border: flat margin around the grid of tiles.
      platform: side of the flat square at each tile's centre.
      spawn_radius: a tile's origin is at the height of the highest ground within this
        distance (along x and y) of its centre.
      base: depth of the heightfield's solid below its lowest point (MuJoCo's ``base_z``).
      slope: (easiest, hardest) slope (rise over run) of the slope types.
      roughness: (easiest, hardest) half-amplitude of the rough slope's noise.
      rough_cell: spacing of the rough slope's noise lattice.
      step_height: (easiest, hardest) riser height of the stairs.
      step_width: tread of the stairs.
      obstacle_height: (easiest, hardest) height of the obstacles.
      obstacle_size: (smallest, largest) side of an obstacle (every level).
      obstacle_count: obstacles per tile.
      stone_size: (easiest, hardest) side of a stepping stone.
      stone_gap: (easiest, hardest) gap between stepping stones.
      pit_depth: (easiest, hardest) depth of the pit under the stepping stones.
      seed: the seed of every random draw (each tile draws from ``(seed, level, column)``).
    """

    levels: int = 10
    types: tuple[str, ...] = TYPES
    tile_size: float = 3.0
    spacing: float = 0.025
    border: float = 1.0
    platform: float = 0.8
    spawn_radius: float = 0.25
    base: float = 0.1
    slope: Pair = (0.0, 0.4)
    roughness: Pair = (0.005, 0.02)
    rough_cell: float = 0.05
    step_height: Pair = (0.01, 0.08)
    step_width: float = 0.15
    obstacle_height: Pair = (0.01, 0.06)
    obstacle_size: Pair = (0.1, 0.4)
    obstacle_count: int = 80
    stone_size: Pair = (0.4, 0.12)
    stone_gap: Pair = (0.02, 0.06)
    pit_depth: Pair = (0.01, 0.08)
    seed: int = 0

    def __post_init__(self) -> None:
        for name in ("levels", "obstacle_count", "seed"):
            value = getattr(self, name)
            _check(
                isinstance(value, int | np.integer) and not isinstance(value, bool),
                name,
                f"must be an integer, got {value!r}",
            )
            object.__setattr__(self, name, int(value))
        _check(self.levels >= 1, "levels", "must be >= 1")
        _check(self.seed >= 0, "seed", "must be >= 0")
        _check(not isinstance(self.types, str), "types", "must be a sequence of type names")
        # a list kept as a tuple: the config stays hashable (terrains are cached by config)
        object.__setattr__(self, "types", tuple(self.types))
        _check(len(self.types) >= 1, "types", "must name at least one type")
        unknown = sorted(set(self.types) - set(TYPES))
        _check(not unknown, "types", f"unknown {unknown}; known: {', '.join(TYPES)}")
        _check(self.spacing > 0, "spacing", "must be > 0")
        for name in ("tile_size", "border", "platform"):
            value = getattr(self, name)
            _check(value >= 0, name, "must be >= 0")
            whole = abs(value / self.spacing - round(value / self.spacing)) < 1e-6
            _check(whole, name, "must be a whole number of `spacing`")
        _check(self.tile_size > 0, "tile_size", "must be > 0")
        _check(self.platform < self.tile_size, "platform", "must be smaller than tile_size")
        for name in ("base", "rough_cell", "step_width"):
            _check(getattr(self, name) > 0, name, "must be > 0")
            object.__setattr__(self, name, float(getattr(self, name)))
        _check(self.spawn_radius >= 0, "spawn_radius", "must be >= 0")
        _check(self.obstacle_count >= 0, "obstacle_count", "must be >= 0")
        for name in (*_LEVELLED, "obstacle_size"):
            lo, hi = _pair(getattr(self, name))
            _check(lo >= 0 and hi >= 0, name, "must be an (easiest, hardest) pair >= 0")
            # a list or an array kept as a tuple of floats: the config stays hashable
            object.__setattr__(self, name, (lo, hi))
        _check(min(self.stone_size) > 0, "stone_size", "must be > 0")
        _check(min(self.pit_depth) > 0, "pit_depth", "must be > 0")
        _check(0 < self.obstacle_size[0] <= self.obstacle_size[1], "obstacle_size", "0 < lo <= hi")

    def difficulty(self, level: int) -> float:
        """``level / (levels - 1)``: 0 at the easiest level, 1 at the hardest (0 when there
        is a single level)."""
        if not 0 <= level < self.levels:
            raise ValueError(f"level must be in [0, {self.levels}), got {level}")
        return level / (self.levels - 1) if self.levels > 1 else 0.0

    def at(self, name: str, level: int) -> float:
        """The value of the level-dependent field ``name`` (e.g. ``"step_height"``) at
        ``level``: linear from its easiest to its hardest value."""
        if name not in _LEVELLED:
            raise ValueError(f"{name!r} is not level-dependent; those are {', '.join(_LEVELLED)}")
        easy, hard = getattr(self, name)
        return float(easy + self.difficulty(level) * (hard - easy))


class TerrainConfigError(ValueError):
    """A :class:`TerrainConfig` field out of range; ``field`` names it."""

    def __init__(self, field: str, message: str) -> None:
        super().__init__(f"TerrainConfig.{field}: {message}")
        self.field = field


def _pair(value: Any) -> tuple[float, float]:
    """``value`` as two floats; NaNs when it is not two numbers."""
    try:
        if np.ndim(value) == 1 and np.size(value) == 2:
            lo, hi = (float(x) for x in value)
            return lo, hi
    except (TypeError, ValueError):
        pass
    return math.nan, math.nan


def _check(ok: bool, name: str, message: str) -> None:
    if not ok:
        raise TerrainConfigError(name, message)


class Mjcf(NamedTuple):
    """A terrain's MJCF: ``asset`` goes inside ``<asset>``, ``geom`` inside the world body."""

    asset: str
    geom: str


@dataclasses.dataclass(frozen=True, eq=False)
class Terrain:
    """A heightfield and where envs start on it.

    Attributes:
      heights: (nrow, ncol) float32 heights (m), read-only; ``heights[r, c]`` is the ground
        at ``x = corner[0] + c * spacing``, ``y = corner[1] + r * spacing`` (row 0 at the
        lowest y, as MuJoCo's ``hfield_data``).
      spacing: distance between samples (m).
      corner: world (x, y) of sample ``[0, 0]`` (m).
      origins: (levels, columns, 3) float32, read-only: for each tile its centre's world
        (x, y) and ground height (the highest within ``spawn_radius``): where an env of
        that level and column is placed. A user's terrain has one, (1, 1, 3).
      types: the terrain type of each column (``("custom",)`` for a user's terrain).
      config: the generator's config (None for a user's terrain).
      base: depth of the heightfield's solid below its lowest point (m; MuJoCo's
        ``base_z``).
      name: the name of its MJCF ``<hfield>`` and ``<geom>`` (the geom a scene's contact
        pairs name).
      friction: the geom's sliding, torsional and rolling friction.
    """

    heights: np.ndarray
    spacing: float
    corner: tuple[float, float]
    origins: np.ndarray
    types: tuple[str, ...]
    config: TerrainConfig | None = None
    base: float = 0.1
    name: str = "terrain"
    friction: tuple[float, float, float] = FRICTION

    def __post_init__(self) -> None:
        h = _checked(self.heights, self.spacing, "Terrain")
        if not self.base > 0:
            raise ValueError(f"Terrain: base must be > 0, got {self.base}")
        o = np.asarray(self.origins)
        if o.ndim != 3 or o.shape[2] != 3 or o.shape[1] != len(self.types):
            raise ValueError(
                f"Terrain: origins must be (levels, {len(self.types)}, 3), got {o.shape}"
            )
        for name, arr in (("heights", h), ("origins", o)):
            arr = np.array(arr, np.float32)
            arr.flags.writeable = False
            object.__setattr__(self, name, arr)
        object.__setattr__(self, "corner", (float(self.corner[0]), float(self.corner[1])))
        object.__setattr__(self, "spacing", float(self.spacing))
        object.__setattr__(self, "base", float(self.base))  # written into MJCF as text

    @property
    def levels(self) -> int:
        """Rows of tiles (difficulty levels)."""
        return int(self.origins.shape[0])

    @property
    def extent(self) -> tuple[float, float]:
        """Size of the heightfield along x and y (m)."""
        nrow, ncol = self.heights.shape
        return (ncol - 1) * self.spacing, (nrow - 1) * self.spacing

    @property
    def center(self) -> tuple[float, float]:
        """World (x, y) of the heightfield's centre (m)."""
        ex, ey = self.extent
        return self.corner[0] + ex / 2, self.corner[1] + ey / 2

    def tile_bounds(self, level: int, column: int) -> tuple[float, float, float, float]:
        """``(xmin, xmax, ymin, ymax)`` of a generated tile (m)."""
        if self.config is None:
            raise ValueError("tile_bounds: a user's terrain has no tiles")
        c = self.config
        if not (0 <= level < self.levels and 0 <= column < len(self.types)):
            grid = f"{self.levels} x {len(self.types)}"
            raise ValueError(f"tile_bounds: no tile ({level}, {column}) in a {grid} grid")
        x0 = self.corner[0] + c.border + column * c.tile_size
        y0 = self.corner[1] + c.border + level * c.tile_size
        return x0, x0 + c.tile_size, y0, y0 + c.tile_size

    def field(self) -> HeightField:
        """The arrays :mod:`jaxenvs.scenes.height` reads (numpy, float32)."""
        return HeightField(
            heights=self.heights,
            corner=np.asarray(self.corner, np.float32),
            spacing=np.asarray(self.spacing, np.float32),
        )

    def hfield_size(self) -> tuple[float, float, float, float]:
        """MuJoCo's ``size`` of the heightfield: (radius_x, radius_y, elevation_z, base_z).

        MuJoCo scales its samples to [0, 1] (subtracting the lowest, dividing by the range)
        and puts sample ``s`` at height ``geom_z + s * elevation_z`` with the solid down to
        ``geom_z - base_z``; with the geom at :meth:`geom_pos` (its z the lowest height) and
        ``elevation_z`` the range of heights, each sample lands at its height in metres.
        """
        ex, ey = self.extent
        span = float(self.heights.max() - self.heights.min())
        return ex / 2, ey / 2, span if span > 0 else 1.0, self.base

    def geom_pos(self) -> tuple[float, float, float]:
        """World position of the heightfield geom: its centre, at the lowest height."""
        cx, cy = self.center
        return cx, cy, float(self.heights.min())

    def _scaled(self) -> np.ndarray:
        """The heights scaled to [0, 1] as MuJoCo stores them (row 0 at the lowest y)."""
        h = self.heights.astype(np.float64)
        span = float(h.max() - h.min())
        return (h - h.min()) / span if span > 0 else np.zeros_like(h)

    def mjcf(self, geom_attrs: Mapping[str, str] | None = None) -> Mjcf:
        """The MJCF of this terrain: ``<hfield>`` and a ``<geom type="hfield">``, both
        named :attr:`name`, placed so that MuJoCo's surface passes through every sample at
        its height (:meth:`hfield_size`), with :attr:`friction`. ``geom_attrs`` adds or
        overrides attributes of the geom (e.g. ``{"rgba": ".4 .4 .4 1"}``).

        MJCF's ``elevation`` lists the top row (the highest y) first, as an image; the
        rows are written in that order.
        """
        nrow, ncol = self.heights.shape
        size = " ".join(repr(v) for v in self.hfield_size())
        elevation = " ".join(map("{:.7g}".format, self._scaled()[::-1].ravel().tolist()))
        asset = (
            f'<hfield name="{self.name}" nrow="{nrow}" ncol="{ncol}" size="{size}" '
            f'elevation="{elevation}"/>'
        )
        attrs = {"name": self.name, "type": "hfield", "hfield": self.name}
        attrs["pos"] = " ".join(repr(v) for v in self.geom_pos())
        attrs["friction"] = " ".join(repr(float(v)) for v in self.friction)
        attrs.update(geom_attrs or {})
        geom = "<geom " + " ".join(f'{k}="{v}"' for k, v in attrs.items()) + "/>"
        return Mjcf(asset=asset, geom=geom)

    def add_to(self, spec: mujoco.MjSpec) -> None:
        """Add this terrain's ``<hfield>`` and geom (as :meth:`mjcf`) to ``spec``'s world
        body: a scene's ground."""
        nrow, ncol = self.heights.shape
        spec.add_hfield(
            name=self.name,
            nrow=nrow,
            ncol=ncol,
            size=list(self.hfield_size()),
            userdata=self._scaled().ravel().tolist(),
        )
        spec.worldbody.add_geom(
            name=self.name,
            type=mujoco.mjtGeom.mjGEOM_HFIELD,
            hfieldname=self.name,
            pos=list(self.geom_pos()),
            friction=list(self.friction),
            rgba=[0.45, 0.45, 0.5, 1.0],
        )

    @classmethod
    def from_array(
        cls,
        heights: np.ndarray,
        spacing: float,
        center: tuple[float, float] = (0.0, 0.0),
        origin: tuple[float, float] | None = None,
    ) -> Terrain:
        """A terrain of ``heights`` (``(nrow, ncol)``, metres; row 0 at the lowest y) with
        samples ``spacing`` metres apart, centred on world ``center``; envs start at world
        ``origin`` (x, y; the centre when None), on the highest ground within 0.25 m."""
        h = _checked(heights, spacing, "from_array")
        nrow, ncol = h.shape
        corner = (center[0] - (ncol - 1) * spacing / 2, center[1] - (nrow - 1) * spacing / 2)
        xy = center if origin is None else origin
        z = _highest(h, corner, spacing, xy, 0.25)
        origins = np.array([[[xy[0], xy[1], z]]])
        return cls(h, spacing, corner, origins, ("custom",))

    @classmethod
    def from_image(
        cls,
        path: str | Path,
        spacing: float,
        height_scale: float,
        base: float = 0.0,
        center: tuple[float, float] = (0.0, 0.0),
        origin: tuple[float, float] | None = None,
    ) -> Terrain:
        """A terrain from a grayscale image (PNG or any format imageio reads; colour
        images are averaged over their channels, alpha ignored): a pixel of value ``v``
        is at height ``base + height_scale * v / vmax`` (``vmax`` 255 for 8-bit, 65535 for
        16-bit images, 1 for float images), pixels ``spacing`` metres apart, the image's
        top row at the highest y (north up, as MuJoCo reads a PNG heightfield)."""
        import imageio.v3 as iio

        img = raw = np.asarray(iio.imread(path))
        if img.ndim == 3:
            img = img[..., : 3 if img.shape[2] >= 3 else 1].mean(axis=2)
        if img.ndim != 2:
            raise ValueError(f"from_image: {path}: expected a 2-D grayscale image, got {img.shape}")
        vmax = np.iinfo(raw.dtype).max if np.issubdtype(raw.dtype, np.integer) else 1.0
        heights = base + height_scale * img.astype(np.float64)[::-1] / vmax
        return cls.from_array(heights, spacing, center, origin)


def _checked(heights: np.ndarray, spacing: float, who: str) -> np.ndarray:
    """``heights`` as a float64 array, or a ValueError naming ``who``."""
    h = np.asarray(heights, np.float64)
    if h.ndim != 2 or min(h.shape) < 2:
        raise ValueError(f"{who}: heights must be 2-D, at least 2 x 2, got {np.shape(heights)}")
    if not np.all(np.isfinite(h)):
        raise ValueError(f"{who}: heights must be finite")
    if not spacing > 0:
        raise ValueError(f"{who}: spacing must be > 0, got {spacing}")
    return h


def _highest(
    h: np.ndarray, corner: tuple[float, float], spacing: float, xy: tuple[float, float], r: float
) -> float:
    """The highest sample within ``r`` (along x and y) of world ``xy``."""
    nrow, ncol = h.shape
    c = (np.asarray(xy) - np.asarray(corner)) / spacing
    # samples at most r away; the tolerance keeps float noise in c (24.000000000000004)
    # from taking in the sample one spacing beyond r
    lo = np.ceil(c - r / spacing - 1e-6).astype(int)
    hi = np.floor(c + r / spacing + 1e-6).astype(int) + 1
    block = h[max(lo[1], 0) : min(hi[1], nrow), max(lo[0], 0) : min(hi[0], ncol)]
    if block.size == 0:
        raise ValueError(f"origin {tuple(xy)} is off the terrain")
    return float(block.max())


# -------------------------------------------------------------------- the generator
def generate(config: TerrainConfig | None = None) -> Terrain:
    """The terrain of ``config`` (module docstring), centred on the world origin;
    deterministic: the same config gives the same heights on every machine."""
    c = config or TerrainConfig()
    n = round(c.tile_size / c.spacing)
    nb = round(c.border / c.spacing)
    nrow, ncol = 2 * nb + c.levels * n + 1, 2 * nb + len(c.types) * n + 1
    heights = np.zeros((nrow, ncol))
    k = (np.arange(n) - n / 2) * c.spacing  # sample offsets from a tile's centre
    u, v = np.meshgrid(k, k)  # u along x (columns), v along y (rows)
    corner = (-(ncol - 1) * c.spacing / 2, -(nrow - 1) * c.spacing / 2)
    origins = np.zeros((c.levels, len(c.types), 3))
    ring = np.maximum(np.abs(u), np.abs(v))
    for level in range(c.levels):
        for col, kind in enumerate(c.types):
            tile = _Tile(u, v, ring, c, level, np.random.default_rng([c.seed, level, col]))
            r0, c0 = nb + level * n, nb + col * n
            heights[r0 : r0 + n, c0 : c0 + n] = _TILES[kind](tile)
    # the origins once every tile is drawn: a spawn_radius may reach a neighbouring tile
    for level in range(c.levels):
        for col in range(len(c.types)):
            r0, c0 = nb + level * n, nb + col * n
            xy = (corner[0] + (c0 + n / 2) * c.spacing, corner[1] + (r0 + n / 2) * c.spacing)
            origins[level, col] = (*xy, _highest(heights, corner, c.spacing, xy, c.spawn_radius))
    return Terrain(heights, c.spacing, corner, origins, tuple(c.types), c, base=c.base)


class _Tile(NamedTuple):
    """A tile being drawn: its samples' offsets from its centre along x (``u``) and y
    (``v``) and ``ring = max(|u|, |v|)`` (m), the config, its level, its generator."""

    u: np.ndarray
    v: np.ndarray
    ring: np.ndarray
    c: TerrainConfig
    level: int
    rng: np.random.Generator

    @property
    def platform(self) -> np.ndarray:
        return self.ring <= self.c.platform / 2


def _flat(t: _Tile) -> np.ndarray:
    return np.zeros_like(t.u)


def _pyramid(t: _Tile) -> np.ndarray:
    """0 at the edge, ``+-slope * (half - platform / 2)`` on the platform."""
    sign = 1.0 if t.rng.random() < 0.5 else -1.0
    return (
        sign * t.c.at("slope", t.level) * (t.c.tile_size / 2 - np.maximum(t.ring, t.c.platform / 2))
    )


def _rough(t: _Tile) -> np.ndarray:
    c, half = t.c, t.c.tile_size / 2
    base = _pyramid(t)
    m = math.ceil(c.tile_size / c.rough_cell) + 1
    lattice = t.rng.uniform(-1.0, 1.0, (m, m)) * c.at("roughness", t.level)
    gx, gy = (t.u + half) / c.rough_cell, (t.v + half) / c.rough_cell
    i, j = np.minimum(gx.astype(int), m - 2), np.minimum(gy.astype(int), m - 2)
    fx, fy = gx - i, gy - j
    bottom = (1 - fx) * lattice[j, i] + fx * lattice[j, i + 1]
    top = (1 - fx) * lattice[j + 1, i] + fx * lattice[j + 1, i + 1]
    fade = np.clip((half - t.ring) / c.rough_cell, 0.0, 1.0)
    return base + ((1 - fy) * bottom + fy * top) * fade


def _stairs(sign: float) -> Callable[[_Tile], np.ndarray]:
    def stairs(t: _Tile) -> np.ndarray:
        half, width = t.c.tile_size / 2, t.c.step_width
        total = math.floor((half - t.c.platform / 2) / width + 1e-9)
        steps = np.clip(np.floor((half - t.ring) / width + 1e-9), 0, total)
        return sign * t.c.at("step_height", t.level) * steps

    return stairs


def _obstacles(t: _Tile) -> np.ndarray:
    out = np.zeros_like(t.u)
    h, half = t.c.at("obstacle_height", t.level), t.c.tile_size / 2
    for _ in range(t.c.obstacle_count):
        cx, cy = t.rng.uniform(-half, half, 2)
        sx, sy = t.rng.uniform(*t.c.obstacle_size, 2)
        z = h * t.rng.choice([-1.0, -0.5, 0.5, 1.0])
        out[(np.abs(t.u - cx) < sx / 2) & (np.abs(t.v - cy) < sy / 2)] = z
    return np.where(t.platform, 0.0, out)


def _stones(t: _Tile) -> np.ndarray:
    size, gap = t.c.at("stone_size", t.level), t.c.at("stone_gap", t.level)
    depth = t.c.at("pit_depth", t.level)
    pitch, half = size + gap, t.c.tile_size / 2
    rows = np.floor((t.v + half) / pitch).astype(int)  # each sample's row of stones
    shift = t.rng.uniform(0.0, pitch, rows.max() + 1)[rows]
    stone = (np.mod(t.u + half + shift, pitch) < size) & (np.mod(t.v + half, pitch) < size)
    return np.where(stone | t.platform, 0.0, -depth)


_TILES: dict[str, Callable[[_Tile], np.ndarray]] = {
    "flat": _flat,
    "smooth_slope": _pyramid,
    "rough_slope": _rough,
    "stairs_up": _stairs(-1.0),
    "stairs_down": _stairs(1.0),
    "obstacles": _obstacles,
    "stepping_stones": _stones,
}
