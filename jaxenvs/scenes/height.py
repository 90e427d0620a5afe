"""Terrain height and normal at any world (x, y), read from the heightfield itself.

MJX has no ray cast against heightfields, so a task that measures the ground under a body
reads the samples. Everything here is a pure function of a :class:`HeightField` (three
arrays: a pytree, so it can sit in env params, or be closed over as a constant) and of the
query points; it jits, vmaps and differentiates.

The surface is MuJoCo's own: each cell between four samples is split into two triangles
along the diagonal from sample ``(r, c)`` to ``(r + 1, c + 1)`` (MuJoCo's collision prisms,
its ray cast and MJX's prisms all use that diagonal), and the height is linear on each
triangle. :func:`height` therefore agrees with ``mujoco.mj_ray`` cast straight down to
float32 rounding everywhere, stairs edges included (tests/scenes/test_height.py).
:func:`bilinear_height` is the bilinear blend of the same four samples: smooth inside a
cell, but up to a quarter of ``|h00 + h11 - h01 - h10|`` away from the surface MuJoCo
collides with (docs/terrain.md gives the figure on the generated terrain).

Points outside the field get the height of the nearest point on its edge (MuJoCo's ray
misses there).
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

__all__ = [
    "HeightField",
    "bilinear_height",
    "height",
    "height_and_normal",
    "height_scan",
    "normal",
    "scan_grid",
]


class HeightField(NamedTuple):
    """A heightfield's samples and where they lie (a pytree of three arrays).

    Attributes:
      heights: (nrow, ncol) heights in metres; ``heights[r, c]`` is the ground at world
        ``x = corner[0] + c * spacing``, ``y = corner[1] + r * spacing`` (row 0 at the
        lowest y, as MuJoCo's ``hfield_data``).
      corner: (2,) world (x, y) of sample ``[0, 0]`` (m).
      spacing: () distance between neighbouring samples along x and y (m).
    """

    heights: jax.Array | np.ndarray
    corner: jax.Array | np.ndarray
    spacing: jax.Array | np.ndarray


def _cell(field: HeightField, xy: jax.Array) -> tuple[jax.Array, ...]:
    """The cell of each point (row, column of its lower-left sample) and the point's
    fractions (fx, fy) in [0, 1] across it, points outside clamped onto the edge."""
    h = jnp.asarray(field.heights)
    nrow, ncol = h.shape
    g = (jnp.asarray(xy) - jnp.asarray(field.corner)) / jnp.asarray(field.spacing)
    gx = jnp.clip(g[..., 0], 0.0, ncol - 1.0)
    gy = jnp.clip(g[..., 1], 0.0, nrow - 1.0)
    c = jnp.clip(jnp.floor(gx).astype(jnp.int32), 0, ncol - 2)
    r = jnp.clip(jnp.floor(gy).astype(jnp.int32), 0, nrow - 2)
    return r, c, gx - c, gy - r


def _corners(field: HeightField, r: jax.Array, c: jax.Array) -> tuple[jax.Array, ...]:
    """Heights of a cell's four samples: (r, c), (r, c + 1), (r + 1, c), (r + 1, c + 1)."""
    h = jnp.asarray(field.heights)
    return h[r, c], h[r, c + 1], h[r + 1, c], h[r + 1, c + 1]


def height_and_normal(field: HeightField, xy: jax.Array) -> tuple[jax.Array, jax.Array]:
    """The ground height (``...``, m) and unit upward normal (``..., 3``) at world points
    ``xy`` (``..., 2``), on MuJoCo's triangulated surface (module docstring). The normal is
    the face's: constant over each triangle."""
    r, c, fx, fy = _cell(field, xy)
    h00, h10, h01, h11 = _corners(field, r, c)
    lower = fx >= fy  # the triangle (r, c), (r, c + 1), (r + 1, c + 1)
    z = jnp.where(
        lower,
        h00 + fx * (h10 - h00) + fy * (h11 - h10),
        h00 + fy * (h01 - h00) + fx * (h11 - h01),
    )
    s = jnp.asarray(field.spacing)
    dzdx = jnp.where(lower, h10 - h00, h11 - h01) / s
    dzdy = jnp.where(lower, h11 - h10, h01 - h00) / s
    n = jnp.stack([-dzdx, -dzdy, jnp.ones_like(dzdx)], axis=-1)
    return z, n / jnp.linalg.norm(n, axis=-1, keepdims=True)


def height(field: HeightField, xy: jax.Array) -> jax.Array:
    """The ground height (m) at world points ``xy`` (``..., 2``): shape ``...``."""
    return height_and_normal(field, xy)[0]


def normal(field: HeightField, xy: jax.Array) -> jax.Array:
    """The ground's unit upward normal at world points ``xy`` (``..., 2``): ``(..., 3)``."""
    return height_and_normal(field, xy)[1]


def bilinear_height(field: HeightField, xy: jax.Array) -> jax.Array:
    """The bilinear blend of the four samples around each point (m): smooth within a
    cell, but not the surface MuJoCo collides with (module docstring)."""
    r, c, fx, fy = _cell(field, xy)
    h00, h10, h01, h11 = _corners(field, r, c)
    bottom = h00 + fx * (h10 - h00)
    top = h01 + fx * (h11 - h01)
    return bottom + fy * (top - bottom)


def scan_grid(nx: int, ny: int, step: float) -> np.ndarray:
    """Offsets (``nx * ny``, 2) of a centred ``nx`` x ``ny`` grid of points ``step`` metres
    apart, in the body's heading frame (x forward, y left), x varying fastest."""
    if nx < 1 or ny < 1:
        raise ValueError(f"scan_grid: nx and ny must be >= 1, got {nx}, {ny}")
    if not step > 0:
        raise ValueError(f"scan_grid: step must be > 0, got {step}")
    x = (np.arange(nx) - (nx - 1) / 2) * step
    y = (np.arange(ny) - (ny - 1) / 2) * step
    gx, gy = np.meshgrid(x, y)
    return np.stack([gx.ravel(), gy.ravel()], axis=-1).astype(np.float32)


def height_scan(
    field: HeightField, pos: jax.Array, yaw: jax.Array, offsets: jax.Array | np.ndarray
) -> jax.Array:
    """The ground under a yaw-aligned pattern of points around a body, relative to it.

    Args:
      field: the heightfield.
      pos: (3,) the body's world position (m).
      yaw: () the body's heading (rad, counter-clockwise from the world x axis).
      offsets: (K, 2) points in the heading frame (x forward, y left; :func:`scan_grid`).

    Returns:
      (K,) ground height at each point minus the body's height (m; negative where the
      ground is below the body: about ``-0.135`` under a hexapod standing on flat ground).
    """
    pos = jnp.asarray(pos)
    cos, sin = jnp.cos(yaw), jnp.sin(yaw)
    rot = jnp.stack([jnp.stack([cos, -sin]), jnp.stack([sin, cos])])
    points = pos[:2] + jnp.asarray(offsets) @ rot.T
    return height(field, points) - pos[2]
