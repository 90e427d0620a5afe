"""Height queries (jaxenvs.scenes.height) against MuJoCo's own ray cast on the generated
terrain, their normals, jit/vmap/grad, and the yaw-aligned height scan."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
import pytest

from jaxenvs.scenes.height import (
    HeightField,
    bilinear_height,
    height,
    height_and_normal,
    height_scan,
    normal,
    scan_grid,
)
from jaxenvs.scenes.terrain import Terrain, TerrainConfig, generate

# every type at three levels, 1.5 m tiles at the default 2.5 cm spacing
CONFIG = TerrainConfig(levels=3, tile_size=1.5, platform=0.5, border=0.25, obstacle_count=20)


@pytest.fixture(scope="module")
def terrain() -> Terrain:
    return generate(CONFIG)


@pytest.fixture(scope="module")
def world(terrain: Terrain) -> tuple[mujoco.MjModel, mujoco.MjData]:
    asset, geom = terrain.mjcf()
    m = mujoco.MjModel.from_xml_string(
        f"<mujoco><asset>{asset}</asset><worldbody>{geom}</worldbody></mujoco>"
    )
    d = mujoco.MjData(m)
    mujoco.mj_forward(m, d)
    return m, d


def ray_down(world: tuple[mujoco.MjModel, mujoco.MjData], xy: np.ndarray) -> tuple[np.ndarray, ...]:
    """MuJoCo's ``mj_ray`` cast straight down from 10 m: the ground's height and normal."""
    m, d = world
    z, n = np.empty(len(xy)), np.empty((len(xy), 3))
    geom = np.zeros(1, np.int32)
    for i, (x, y) in enumerate(xy):
        out = np.zeros(3)
        dist = mujoco.mj_ray(
            m, d, np.array([x, y, 10.0]), np.array([0, 0, -1.0]), None, 1, -1, geom, out
        )
        assert dist >= 0, (x, y)
        z[i], n[i] = 10.0 - dist, out
    return z, n


def random_points(terrain: Terrain, count: int, seed: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    ex, ey = terrain.extent
    low = np.asarray(terrain.corner)
    return low + rng.uniform(0.0, 1.0, (count, 2)) * np.array([ex, ey])


def test_height_and_normal_agree_with_mujocos_ray(terrain: Terrain, world) -> None:  # type: ignore[no-untyped-def]
    """At random points (stairs edges, obstacles' sides and stones' rims included: the
    surface is MuJoCo's own triangulation, so nothing is excluded) to 1 mm; the bilinear
    blend does not match there."""
    xy = random_points(terrain, 3000, seed=0)
    # the samples themselves, where the steepest faces meet
    nrow, ncol = terrain.heights.shape
    rows, cols = np.meshgrid(np.arange(1, nrow - 1, 7), np.arange(1, ncol - 1, 5), indexing="ij")
    at = np.asarray(terrain.corner) + terrain.spacing * np.stack([cols.ravel(), rows.ravel()], -1)
    query = jax.jit(
        lambda p: (*height_and_normal(terrain.field(), p), bilinear_height(terrain.field(), p))
    )
    z, n, bilinear = (
        np.asarray(a) for a in query(jnp.asarray(np.concatenate([xy, at]), jnp.float32))
    )
    ray_z, ray_n = ray_down(world, np.concatenate([xy, at]))
    assert np.abs(z - ray_z).max() < 1e-3
    assert np.abs(n[: len(xy)] - ray_n[: len(xy)]).max() < 1e-3  # on an edge it is either face's
    assert np.abs(z[len(xy) :] - terrain.heights[rows.ravel(), cols.ravel()]).max() < 1e-5
    assert np.abs(bilinear - ray_z).max() > 1e-3  # why the triangles


def test_normals_unit_and_finite_differences(terrain: Terrain) -> None:
    """Inside each triangle (points kept 2 % of a cell off its edges and diagonal) the normal
    is ``(-dz/dx, -dz/dy, 1)`` normalised, from central differences of :func:`height`."""
    rng = np.random.default_rng(1)
    nrow, ncol = terrain.heights.shape
    cell = np.stack([rng.integers(0, ncol - 1, 500), rng.integers(0, nrow - 1, 500)], -1)
    frac = rng.uniform(0.04, 0.96, (500, 2))
    frac = frac[np.abs(frac[:, 0] - frac[:, 1]) > 0.04]
    xy = np.asarray(terrain.corner) + terrain.spacing * (cell[: len(frac)] + frac)
    f = terrain.field()
    f64 = HeightField(*(np.asarray(a, np.float64) for a in f))
    eps = 1e-4 * terrain.spacing
    steps = np.array([[eps, 0], [-eps, 0], [0, eps], [0, -eps]])

    @jax.jit
    def probe(p: jax.Array) -> tuple[jax.Array, jax.Array]:
        return height(f64, p[None] + steps[:, None]), normal(f64, p)

    with jax.enable_x64(True):
        z, n = (np.asarray(a) for a in probe(xy))
    dx, dy = (z[0] - z[1]) / (2 * eps), (z[2] - z[3]) / (2 * eps)
    expected = np.stack([-dx, -dy, np.ones_like(dx)], -1)
    expected /= np.linalg.norm(expected, axis=-1, keepdims=True)
    assert np.abs(np.linalg.norm(n, axis=-1) - 1).max() < 1e-9
    assert np.abs(n - expected).max() < 1e-6


def test_jit_vmap_grad_and_params(terrain: Terrain) -> None:
    f = terrain.field()
    xy = jnp.asarray(random_points(terrain, 64, seed=2), jnp.float32)
    off = jnp.array([[terrain.corner[0] - 5.0, 0.0], [terrain.corner[0], 0.0]])

    @jax.jit
    def run(field: HeightField, p: jax.Array) -> tuple[jax.Array, ...]:
        # the field as a traced argument (it may live in env params) and as a constant
        as_arg = jax.vmap(height, in_axes=(None, 0))(field, p)
        as_const = jax.vmap(lambda q: height(f, q))(p)
        grad = jax.vmap(jax.grad(lambda q: height(field, q)))(p)
        return as_arg, as_const, grad, normal(field, p), height(field, off)

    as_arg, as_const, grad, n, edge = (np.asarray(a) for a in run(jax.tree.map(jnp.asarray, f), xy))
    direct, _ = ray_free_reference(terrain, np.asarray(xy))
    assert np.abs(as_arg - direct).max() < 1e-5 and np.abs(as_arg - as_const).max() < 1e-6
    assert np.abs(grad + n[:, :2] / n[:, 2:]).max() < 1e-3
    assert edge[0] == edge[1]  # points off the field read its nearest edge


def ray_free_reference(terrain: Terrain, xy: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """MuJoCo's triangulation in numpy (float64): the height at ``xy`` and its cells'
    indices, for checks that need no ray cast."""
    g = (xy - np.asarray(terrain.corner)) / terrain.spacing
    c, r = np.floor(g[:, 0]).astype(int), np.floor(g[:, 1]).astype(int)
    fx, fy = g[:, 0] - c, g[:, 1] - r
    h = terrain.heights.astype(np.float64)
    h00, h10, h01, h11 = h[r, c], h[r, c + 1], h[r + 1, c], h[r + 1, c + 1]
    lower = h00 + fx * (h10 - h00) + fy * (h11 - h10)
    upper = h00 + fy * (h01 - h00) + fx * (h11 - h01)
    return np.where(fx >= fy, lower, upper), np.stack([r, c], -1)


def test_height_scan_is_yaw_aligned() -> None:
    """On a plane ``z = 0.1 x - 0.2 y + 0.3`` the scan is the plane at the rotated points
    minus the body's height; offset (1, 0) at yaw pi/2 reads the point 1 m along +y."""
    x = np.arange(-40, 41) * 0.05
    gx, gy = np.meshgrid(x, x)
    plane = Terrain.from_array(0.1 * gx - 0.2 * gy + 0.3, spacing=0.05).field()
    offsets = scan_grid(5, 3, 0.1)
    assert offsets.shape == (15, 2)
    assert offsets[:5, 0] == pytest.approx([-0.2, -0.1, 0.0, 0.1, 0.2], abs=1e-7)
    assert np.all(offsets[:5, 1] == offsets[0, 1])  # x varies fastest
    pos, yaw = jnp.array([0.3, -0.4, 0.5]), 0.7
    rot = np.array([[np.cos(yaw), -np.sin(yaw)], [np.sin(yaw), np.cos(yaw)]])
    pts = np.asarray(pos[:2]) + offsets @ rot.T
    expected = 0.1 * pts[:, 0] - 0.2 * pts[:, 1] + 0.3 - 0.5

    @jax.jit
    def run(p: jax.Array, y: jax.Array) -> tuple[jax.Array, ...]:
        one = height_scan(plane, jnp.zeros(3), jnp.asarray(np.pi / 2), np.array([[1.0, 0.0]]))
        many = jax.vmap(height_scan, in_axes=(None, 0, 0, None))(
            plane, jnp.stack([p, p]), jnp.stack([y, y]), offsets
        )
        return height_scan(plane, p, y, offsets), one, many

    scan, one, many = (np.asarray(a) for a in run(pos, jnp.asarray(yaw)))
    assert np.abs(scan - expected).max() < 1e-5
    assert float(one[0]) == pytest.approx(-0.2 * 1.0 + 0.3, abs=1e-5)
    assert np.abs(many - expected).max() < 1e-5  # a batch of bodies


def test_scan_grid_rejects_bad_input() -> None:
    with pytest.raises(ValueError, match="nx and ny"):
        scan_grid(0, 3, 0.1)
    with pytest.raises(ValueError, match="step"):
        scan_grid(3, 3, 0.0)
