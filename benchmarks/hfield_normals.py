"""Contact normals of a foot on a FLAT heightfield, under MuJoCo C and MJX.

A sphere of the hexapod's foot radius (1.2 cm) is placed at ``--points`` random points of a
flat heightfield of 2.5 cm cells (the terrain's spacing), pressed into it by a depth drawn
uniformly in 0-12 mm, and collided once (``mj_forward`` / ``mjx.forward``). On a plane
every contact normal is vertical; on a heightfield each engine collides the sphere with the
triangles (MJX) or triangular prisms (MuJoCo C) under it, and near a cell's edge the normal
can tilt. Per band of penetration: the share of placements with a contact whose normal's
vertical component is below 0.99, the lowest such component, and the mean contact count.
MuJoCo C is also run with MPR instead of the native CCD and with a tighter CCD tolerance.

    python benchmarks/hfield_normals.py --points 400
"""

from __future__ import annotations

import argparse

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
from mujoco import mjx

FOOT = 0.012
XML = f"""
<mujoco>
  <option timestep="0.01" cone="elliptic" solver="Newton"/>
  <asset><hfield name="h" nrow="41" ncol="41" size="0.5 0.5 0.1 0.1"/></asset>
  <worldbody>
    <geom name="terrain" type="hfield" hfield="h"/>
    <body name="foot" pos="0 0 0.2">
      <freejoint/><geom type="sphere" size="{FOOT}" mass="0.3"/>
    </body>
  </worldbody>
</mujoco>"""
#: the flat ground's height (the samples at half of the 0.1 m elevation)
GROUND = 0.05
BANDS = ((0.0, 0.003), (0.003, 0.006), (0.006, 0.012))


def model() -> mujoco.MjModel:
    m = mujoco.MjModel.from_xml_string(XML)
    m.hfield_data[:] = 0.5
    return m


def placements(points: int, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """``(points, 7)`` free-joint poses and each one's penetration depth (m)."""
    rng = np.random.default_rng(seed)
    xy = rng.uniform(-0.2, 0.2, (points, 2))
    depth = rng.uniform(0.0, 2 * FOOT, points)
    qpos = np.zeros((points, 7))
    qpos[:, :2], qpos[:, 2], qpos[:, 3] = xy, GROUND + FOOT - depth, 1.0
    return qpos, depth


def c_normals(m: mujoco.MjModel, qpos: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Each placement's lowest normal z and contact count under MuJoCo C."""
    d = mujoco.MjData(m)
    low, count = np.ones(len(qpos)), np.zeros(len(qpos))
    for i, q in enumerate(qpos):
        mujoco.mj_resetData(m, d)
        d.qpos[:] = q
        mujoco.mj_forward(m, d)
        if d.ncon:
            low[i] = min(d.contact[j].frame[2] for j in range(d.ncon))
        count[i] = d.ncon
    return low, count


def mjx_normals(m: mujoco.MjModel, qpos: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Each placement's lowest normal z and active contact count under MJX."""
    mx = mjx.put_model(m)

    def one(q: jax.Array) -> tuple[jax.Array, jax.Array]:
        d = mjx.forward(mx, mjx.make_data(mx).replace(qpos=q))
        c = d._impl.contact if hasattr(d, "_impl") else d.contact
        active = c.dist < 0
        return jnp.where(active, c.frame[:, 0, 2], 1.0).min(), active.sum()

    low, count = jax.jit(jax.vmap(one))(jnp.asarray(qpos, jnp.float32))
    return np.asarray(low), np.asarray(count)


def report(label: str, depth: np.ndarray, low: np.ndarray, count: np.ndarray) -> None:
    cells = []
    for lo, hi in BANDS:
        sel = (depth >= lo) & (depth < hi)
        cells.append(
            f"{lo * 1e3:.0f}-{hi * 1e3:.0f} mm: {np.mean(low[sel] < 0.99):.0%} below 0.99, "
            f"lowest {low[sel].min():.3f}, {count[sel].mean():.1f} contacts"
        )
    print(f"{label:28s} " + " | ".join(cells))


def main() -> None:
    parser = argparse.ArgumentParser(description=(__doc__ or "").splitlines()[0])
    parser.add_argument("--points", type=int, default=400)
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()
    qpos, depth = placements(args.points, args.seed)
    m = model()
    report("MuJoCo C", depth, *c_normals(m, qpos))
    m.opt.disableflags |= int(mujoco.mjtDisableBit.mjDSBL_NATIVECCD)
    report("MuJoCo C, MPR", depth, *c_normals(m, qpos))
    m = model()
    m.opt.ccd_tolerance, m.opt.ccd_iterations = 1e-9, 200
    report("MuJoCo C, tight CCD", depth, *c_normals(m, qpos))
    report("MJX", depth, *mjx_normals(model(), qpos))


if __name__ == "__main__":
    main()
