"""Bodies dropped on a generated heightfield come to rest on the ground that
jaxenvs.scenes.height reports: under MuJoCo C, and under MJX (the model's heightfield put on
device, collided with a sphere and a capsule: the kinds of the hexapod's feet and shins)."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
import pytest

from jaxenvs.scenes.height import height
from jaxenvs.scenes.terrain import Terrain, TerrainConfig, generate

RADIUS = 0.02  # the sphere's; the capsule's is 0.015, half-length 0.04
STEPS = 300  # 1.5 s of 5 ms


@pytest.fixture(scope="module")
def bumpy() -> Terrain:
    """One rough tile at the easiest level: flat with +-5 mm of noise."""
    return generate(TerrainConfig(levels=1, types=("rough_slope",), tile_size=1.0, platform=0.4))


def drop_model(terrain: Terrain) -> tuple[mujoco.MjModel, mujoco.MjData]:
    """A sphere and a capsule 5 cm above the terrain near its origin, at rest."""
    asset, geom = terrain.mjcf()
    xml = f"""<mujoco><option timestep="0.005"/><asset>{asset}</asset><worldbody>{geom}
      <body name="ball"><freejoint/><geom type="sphere" size="{RADIUS}" mass="0.1"/></body>
      <body name="shin"><freejoint/>
        <geom type="capsule" size="0.015" fromto="-0.04 0 0 0.04 0 0" mass="0.1"/></body>
    </worldbody></mujoco>"""
    m = mujoco.MjModel.from_xml_string(xml)
    d = mujoco.MjData(m)
    x, y, z = terrain.origins[0, 0]
    d.qpos[:3] = (x + 0.1, y + 0.05, z + 0.05)
    d.qpos[7:10] = (x - 0.1, y - 0.12, z + 0.05)
    return m, d


def check_rest(terrain: Terrain, qpos: np.ndarray, qvel: np.ndarray) -> None:
    """The sphere on the ground below its centre, the capsule on the higher ground below its
    two ends (3 mm: MuJoCo's soft contact and the bumps' tilt), both settled vertically (the
    sphere may roll over the bumps)."""
    ball, shin = qpos[:3], qpos[7:10]
    half = 0.04 * _axis(qpos[10:14])
    points = np.stack([ball[:2], shin[:2] - half, shin[:2] + half])
    ground = np.asarray(height(terrain.field(), jnp.asarray(points, jnp.float32)))
    assert abs(qvel[2]) < 0.02 and abs(qvel[8]) < 0.02, qvel
    assert abs(ball[2] - RADIUS - ground[0]) < 3e-3, (ball, ground)
    assert abs(shin[2] - 0.015 - ground[1:].max()) < 3e-3, (shin, ground)


def _axis(quat: np.ndarray) -> np.ndarray:
    """The horizontal part of a body's x axis, for orientation ``quat`` (w x y z)."""
    mat = np.zeros(9)
    mujoco.mju_quat2Mat(mat, np.asarray(quat, np.float64))
    return mat.reshape(3, 3)[:2, 0]


def test_bodies_rest_on_the_ground_under_mujoco_c(bumpy: Terrain) -> None:
    m, d = drop_model(bumpy)
    for _ in range(STEPS):
        mujoco.mj_step(m, d)
    check_rest(bumpy, d.qpos.copy(), d.qvel.copy())


@pytest.mark.full  # MJX's heightfield collision compiles for about 30 s on two cores
def test_bodies_rest_on_the_ground_under_mjx(bumpy: Terrain) -> None:
    from mujoco import mjx

    m, d = drop_model(bumpy)
    mx = mjx.put_model(m)
    dx = mjx.put_data(m, d)
    out = jax.jit(lambda x: jax.lax.fori_loop(0, STEPS, lambda _, s: mjx.step(mx, s), x))(dx)
    check_rest(bumpy, np.asarray(out.qpos, np.float64), np.asarray(out.qvel, np.float64))
