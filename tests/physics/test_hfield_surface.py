"""MuJoCo C's sphere-on-heightfield collider of jaxenvs (``native/hfield.cc``).

What these check: on flat cells a pressed sphere gets exactly one contact, vertical, as
deep as it is pressed, where MuJoCo's own collider (still used by a model that does not
ask) tilts; against a step's riser the sphere gets one contact on the tread and one on the
riser, on a step's edge one along the line from the edge to its centre; on generated rough
terrain each contact's surface point is on the ground that ``jaxenvs.scenes.height``
reports (and so MuJoCo's ray cast) and the deepest contact is the true distance; a scene
on a heightfield asks for the collider unless told ``"mujoco"``; the hexapod standing on a
flat heightfield touches it with six vertical contacts.
"""

from __future__ import annotations

import warnings

import jax.numpy as jnp
import mujoco
import numpy as np
import pytest

from jaxenvs.config import ConfigError
from jaxenvs.physics import native
from jaxenvs.robots.hexapod import STAND_HEIGHT, Hexapod
from jaxenvs.scenes import Scene
from jaxenvs.scenes.height import height
from jaxenvs.scenes.terrain import Terrain, TerrainConfig, generate
from jaxenvs.tasks.hexapod.rough import JoystickRoughConfig

RADIUS = 0.012  # the hexapod's foot


@pytest.fixture(scope="module")
def numeric() -> str:
    name = native.hfield_surface()
    assert name is not None, "the native library (built at install) provides the collider"
    return name


def world(terrain: Terrain, numeric: str | None) -> mujoco.MjModel:
    """``terrain`` and a free sphere of the foot's radius; ``numeric`` asks for the collider."""
    asset, geom = terrain.mjcf()
    custom = f'<custom><numeric name="{numeric}" data="1"/></custom>' if numeric else ""
    return mujoco.MjModel.from_xml_string(
        f"""<mujoco>{custom}<asset>{asset}</asset><worldbody>{geom}
        <body><freejoint/><geom type="sphere" size="{RADIUS}" mass="0.01"/></body>
        </worldbody></mujoco>"""
    )


def contacts(m: mujoco.MjModel, centre: np.ndarray) -> list[tuple[float, np.ndarray, np.ndarray]]:
    """``(dist, pos, normal)`` of each contact with the sphere's centre at ``centre``."""
    d = mujoco.MjData(m)
    d.qpos[:3], d.qpos[3] = centre, 1.0
    mujoco.mj_forward(m, d)
    return [(c.dist, c.pos.copy(), c.frame[:3].copy()) for c in d.contact[: d.ncon]]


def test_flat_cells_give_one_vertical_contact_as_deep_as_pressed(numeric: str) -> None:
    flat = Terrain.from_array(np.full((41, 41), 0.3), 0.025)
    ours, stock = world(flat, numeric), world(flat, None)
    rng = np.random.default_rng(0)
    tilted = 0
    for _ in range(100):
        depth = rng.uniform(0.0, RADIUS)
        centre = np.array([*rng.uniform(-0.2, 0.2, 2), 0.3 + RADIUS - depth])
        (dist, pos, normal), *more = contacts(ours, centre)
        assert not more
        np.testing.assert_allclose(normal, [0, 0, 1], atol=1e-12)
        assert dist == pytest.approx(-depth, abs=1e-7)  # the geom at float32 height
        np.testing.assert_allclose(pos, [*centre[:2], 0.3 - depth / 2], atol=1e-7)
        tilted += min(n[2] for _, _, n in contacts(stock, centre)) < 0.99
    assert tilted > 30  # MuJoCo's prisms, for a model that does not ask: unchanged


def test_a_step_gives_its_tread_and_riser_or_its_edge(numeric: str) -> None:
    """A 5 cm step at x = 0 (a riser one cell wide, from x = 0 to 0.025)."""
    heights = np.zeros((21, 21))
    heights[:, 11:] = 0.05
    m = world(Terrain.from_array(heights, 0.025), numeric)
    # at the riser's foot: pressed 2 mm into the tread and 4.8 mm into the riser, whose
    # normal is (-2, 0, 1) / sqrt(5) (it rises 5 cm over 2.5)
    centre = np.array([-0.003, 0.01, RADIUS - 0.002])
    found = contacts(m, centre)
    normals = sorted((tuple(np.round(n, 6)) for _, _, n in found), key=lambda n: n[2])
    assert len(found) == 2, found
    np.testing.assert_allclose(normals[1], [0, 0, 1], atol=1e-9)
    np.testing.assert_allclose(normals[0], [-0.894427, 0, 0.447214], atol=1e-6)
    # on the top edge: the normal from the edge (x = 0.025, z = 0.05) to the centre
    centre = np.array([0.025 - 0.006, 0.01, 0.05 + 0.008])
    ((dist, _, normal),) = contacts(m, centre)
    arm = np.array([-0.006, 0.0, 0.008])
    np.testing.assert_allclose(normal, arm / np.linalg.norm(arm), atol=1e-9)
    assert dist == pytest.approx(np.linalg.norm(arm) - RADIUS, abs=1e-9)


def test_rough_ground_contacts_lie_on_the_reported_ground(numeric: str) -> None:
    terrain = generate(
        TerrainConfig(levels=2, types=("rough_slope", "stairs_up"), tile_size=1.0, platform=0.2)
    )
    m = world(terrain, numeric)
    field = terrain.field()
    rng = np.random.default_rng(1)
    low = np.asarray(terrain.corner) + 0.1
    xy = low + rng.uniform(0.0, 1.0, (200, 2)) * (np.asarray(terrain.extent) - 0.2)
    ground = np.asarray(height(field, jnp.asarray(xy, jnp.float32)), np.float64)
    hits = 0
    for (x, y), z in zip(xy, ground, strict=True):
        found = contacts(m, np.array([x, y, z + RADIUS - 0.002]))
        assert found, (x, y)  # pressed 2 mm below the ground under its centre
        for dist, pos, normal in found:
            surface = pos - normal * dist / 2
            below = float(height(field, jnp.asarray(surface[:2], jnp.float32)))
            assert abs(surface[2] - below) < 1e-3, (x, y, surface, below)
            assert normal[2] > 0 and dist < 0
        deepest = min(d for d, _, _ in found)
        assert deepest <= -0.002 + 1e-5  # at least as deep as straight down
        hits += len(found)
    assert hits >= 200


def _triangles(heights: np.ndarray, size: np.ndarray) -> np.ndarray:
    """``(2 (nrow - 1) (ncol - 1), 3, 3)``: MuJoCo's triangles of a heightfield's samples
    (``hfield_data``, row 0 at the lowest y), in the heightfield's frame."""
    nrow, ncol = heights.shape
    x = np.linspace(-size[0], size[0], ncol)
    y = np.linspace(-size[1], size[1], nrow)
    v = np.stack([*np.meshgrid(x, y), heights * size[2]], axis=-1)
    a, b, c, d = v[:-1, :-1], v[:-1, 1:], v[1:, 1:], v[1:, :-1]
    return np.concatenate([np.stack([a, b, c], -2), np.stack([a, d, c], -2)]).reshape(-1, 3, 3)


def _closest(p: np.ndarray, tri: np.ndarray) -> np.ndarray:
    """Each triangle's point closest to ``p``, by brute force: the face's projection where
    inside, else the closest of the three edges' closest points."""
    a, b, c = tri[:, 0], tri[:, 1], tri[:, 2]
    n = np.cross(b - a, c - a)
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    proj = p - np.sum((p - a) * n, axis=1, keepdims=True) * n
    # barycentric coordinates of the projection
    v0, v1, v2 = b - a, c - a, proj - a
    d00, d01, d11 = (v0 * v0).sum(1), (v0 * v1).sum(1), (v1 * v1).sum(1)
    d20, d21 = (v2 * v0).sum(1), (v2 * v1).sum(1)
    den = d00 * d11 - d01 * d01
    v, w = (d11 * d20 - d01 * d21) / den, (d00 * d21 - d01 * d20) / den
    inside = (v >= 0) & (w >= 0) & (v + w <= 1)
    best = proj.copy()
    gap = np.full(len(tri), np.inf)
    for s, e in ((a, b), (b, c), (c, a)):
        t = np.clip(((p - s) * (e - s)).sum(1) / ((e - s) ** 2).sum(1), 0, 1)[:, None]
        x = s + t * (e - s)
        dist = np.linalg.norm(p - x, axis=1)
        closer = ~inside & (dist < gap)
        best[closer], gap[closer] = x[closer], dist[closer]
    return best


@pytest.mark.parametrize("euler", ["0 0 0", "30 20 50"])
def test_random_ground_agrees_with_a_brute_force(numeric: str, euler: str) -> None:
    """Random samples, a heightfield geom turned or not, spheres placed anywhere from half
    a radius below the surface to above it: from above, the deepest contact is the true
    distance to the surface (none where it is out of reach) and every contact's point is
    on the surface; from below, one contact, pointing up."""
    rng = np.random.default_rng(3)
    nrow, ncol, radius = 7, 9, 0.02
    data = " ".join(f"{h:.6f}" for h in rng.uniform(0, 1, nrow * ncol))
    m = mujoco.MjModel.from_xml_string(
        f"""<mujoco><custom><numeric name="{numeric}" data="1"/></custom><asset>
        <hfield name="h" nrow="{nrow}" ncol="{ncol}" size="0.15 0.1 0.05 0.05"
          elevation="{data}"/></asset><worldbody>
        <geom type="hfield" hfield="h" pos="0.1 -0.2 0.3" euler="{euler}"/>
        <body><freejoint/><geom type="sphere" size="{radius}" mass="0.01"/></body>
        </worldbody></mujoco>"""
    )
    size = m.hfield_size[0]
    tris = _triangles(np.asarray(m.hfield_data, np.float64).reshape(nrow, ncol), size)
    d = mujoco.MjData(m)
    mujoco.mj_kinematics(m, d)
    pos, rot = d.geom_xpos[0].copy(), d.geom_xmat[0].reshape(3, 3).copy()
    seen = {"above": 0, "below": 0, "none": 0}
    for _ in range(300):
        p = np.array([*rng.uniform(-size[:2], size[:2]), 0.0])
        (under,) = [t for t in tris if _on(p[:2], t)][:1]
        n = np.cross(under[1] - under[0], under[2] - under[0])
        n /= np.linalg.norm(n) * np.sign(n[2])
        ground = under[0][2] - ((p[:2] - under[0][:2]) @ n[:2]) / n[2]
        p[2] = ground + rng.uniform(-0.5, 1.5) * radius
        found = contacts(m, pos + rot @ p)
        local = [(dist, rot.T @ (x - pos), rot.T @ normal) for dist, x, normal in found]
        if p[2] < ground:
            seen["below"] += 1
            assert len(local) == 1 and local[0][2][2] > 0, (p, local)
            continue
        true = np.linalg.norm(_closest(p, tris) - p, axis=1).min() - radius
        if true >= 0:
            seen["none"] += 1
            assert not local, (p, true, local)
            continue
        seen["above"] += 1
        assert min(dist for dist, _, _ in local) == pytest.approx(true, abs=1e-6)
        for dist, x, normal in local:
            q = x - normal * dist / 2
            assert any(_on(q[:2], t) and abs(_z(q[:2], t) - q[2]) < 1e-6 for t in tris)
            assert np.linalg.norm(p - q) - radius == pytest.approx(dist, abs=1e-6)
    assert min(seen.values()) >= 20, seen


def _on(xy: np.ndarray, tri: np.ndarray) -> bool:
    """True if ``xy`` lies over triangle ``tri`` (within 1e-9 m)."""
    a, b, c = tri[:, :2]
    m = np.array([b - a, c - a]).T
    v, w = np.linalg.solve(m, xy - a)
    return bool(v >= -1e-9 and w >= -1e-9 and v + w <= 1 + 1e-9)


def _z(xy: np.ndarray, tri: np.ndarray) -> float:
    """The height of triangle ``tri``'s plane over ``xy``."""
    a, b, c = tri
    v, w = np.linalg.solve(np.array([b[:2] - a[:2], c[:2] - a[:2]]).T, xy - a[:2])
    return float(a[2] + v * (b[2] - a[2]) + w * (c[2] - a[2]))


def test_a_heightfield_scene_asks_for_it_unless_told_mujoco(numeric: str) -> None:
    flat = Terrain.from_array(np.zeros((9, 9)), 0.025)
    names = lambda m: [m.numeric(i).name for i in range(m.nnumeric)]  # noqa: E731
    assert numeric in names(Hexapod().scene(flat).spec().compile())
    assert numeric not in names(Hexapod().scene(flat, hfield_contact="mujoco").spec().compile())
    assert numeric not in names(Hexapod().scene().spec().compile())  # a plane: nothing to ask
    with pytest.raises(ValueError, match="hfield_contact must be one of"):
        Scene(Hexapod.xml, hfield_contact="prisms")
    with pytest.raises(ConfigError, match="hfield_contact"):
        JoystickRoughConfig(hfield_contact="prisms").validate()


def test_the_hexapod_stands_on_a_flat_heightfield_with_six_vertical_contacts(
    numeric: str,
) -> None:
    del numeric
    flat = Terrain.from_array(np.full((81, 81), 0.2), 0.025)
    m = Hexapod().scene(flat).spec().compile()
    d = mujoco.MjData(m)
    d.qpos[:3] = (0.013, -0.007, 0.2 + STAND_HEIGHT - 0.006)  # the feet 3 mm in
    d.qpos[3] = 1.0
    mujoco.mj_forward(m, d)
    assert d.ncon == 6
    np.testing.assert_allclose(d.contact.frame[:, :3], [[0, 0, 1]] * 6, atol=1e-12)


def test_without_the_native_library_the_c_engine_warns_once(monkeypatch) -> None:
    """Where the library is not built, stepping a model that asks for the collider warns
    (MuJoCo's own collider steps it); a model that does not ask says nothing."""
    flat = Terrain.from_array(np.zeros((9, 9)), 0.025)
    asking = Hexapod().scene(flat).spec().compile()
    plain = Hexapod().scene(flat, hfield_contact="mujoco").spec().compile()
    monkeypatch.setattr(native, "hfield_surface", lambda: None)
    native._warn_no_surface.cache_clear()
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        native.prepare(plain)
    with pytest.warns(RuntimeWarning, match="heightfield's prisms instead"):
        native.prepare(asking)
    native._warn_no_surface.cache_clear()
