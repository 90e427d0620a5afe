"""Contact normals of a foot on a FLAT heightfield, under MuJoCo C and MJX.

A sphere of the hexapod's foot radius (1.2 cm) is placed at ``--points`` random points of
a flat heightfield of 2.5 cm cells (the terrain's spacing), pressed into it by a depth
drawn uniformly in 0-12 mm (the foot's radius), and collided once (``mj_forward`` /
``mjx.forward``). On a plane every contact normal is vertical; on a heightfield each
engine collides the sphere with the triangles (MJX) or the triangular prisms (MuJoCo C)
under it, and near a cell's edge the normal can tilt. Per band of penetration: the share
of placements with a contact whose normal's vertical component is below 0.99, the lowest
such component, and the mean contact count. MuJoCo C is also run with MPR instead of the
native CCD and with a tighter CCD tolerance, and with jaxenvs' surface collider
(``jaxenvs.physics.native.hfield_surface``, the terrain tasks' default under MuJoCo C).

    python benchmarks/hfield_normals.py --points 400 --json hfield_normals_cpu2

``--json`` records one row per engine setting and band: ``engine``, ``band_mm``,
``placements``, ``share_below_0_99``, ``lowest_normal_z`` and ``mean_contacts``.
"""

from __future__ import annotations

import argparse
from typing import Any

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
import results_io
from mujoco import mjx

from jaxenvs.physics import native

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


def model(surface: bool = False) -> mujoco.MjModel:
    """The heightfield and the foot; ``surface``: the model asks for jaxenvs' collider."""
    xml = XML
    if surface:
        name = native.hfield_surface()
        if name is None:
            raise SystemExit("jaxenvs' native library is not built: no surface collider")
        xml = XML.replace("<asset>", f'<custom><numeric name="{name}" data="1"/></custom><asset>')
    m = mujoco.MjModel.from_xml_string(xml)
    m.hfield_data[:] = 0.5
    return m


def placements(points: int, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """``(points, 7)`` free-joint poses and each one's penetration depth (m)."""
    rng = np.random.default_rng(seed)
    xy = rng.uniform(-0.2, 0.2, (points, 2))
    depth = rng.uniform(0.0, FOOT, points)
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


def rows(label: str, depth: np.ndarray, low: np.ndarray, count: np.ndarray) -> list[dict[str, Any]]:
    """One row per band of penetration (module docstring), printed as one line."""
    out, cells = [], []
    for lo, hi in BANDS:
        sel = (depth >= lo) & (depth < hi)
        row = {
            "engine": label,
            "band_mm": [lo * 1e3, hi * 1e3],
            "placements": int(sel.sum()),
            "share_below_0_99": float(np.mean(low[sel] < 0.99)),
            "lowest_normal_z": float(low[sel].min()),
            "mean_contacts": float(count[sel].mean()),
        }
        out.append(row)
        cells.append(
            f"{lo * 1e3:.0f}-{hi * 1e3:.0f} mm: {row['share_below_0_99']:.0%} below 0.99, "
            f"lowest {row['lowest_normal_z']:.3f}, {row['mean_contacts']:.1f} contacts"
        )
    print(f"{label:28s} " + " | ".join(cells))
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=(__doc__ or "").splitlines()[0])
    parser.add_argument("--points", type=int, default=400)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--json", metavar="NAME", help=results_io.HELP)
    args = parser.parse_args()
    qpos, depth = placements(args.points, args.seed)
    m = model()
    found = rows("MuJoCo C", depth, *c_normals(m, qpos))
    m.opt.disableflags |= int(mujoco.mjtDisableBit.mjDSBL_NATIVECCD)
    found += rows("MuJoCo C, MPR", depth, *c_normals(m, qpos))
    m = model()
    m.opt.ccd_tolerance, m.opt.ccd_iterations = 1e-9, 200
    found += rows("MuJoCo C, tight CCD", depth, *c_normals(m, qpos))
    found += rows("MuJoCo C, jaxenvs surface", depth, *c_normals(model(surface=True), qpos))
    found += rows("MJX", depth, *mjx_normals(model(), qpos))
    if args.json:
        rec = results_io.record(
            args.json,
            "contact normals of a 1.2 cm sphere on a flat heightfield of 2.5 cm cells",
            found,
            engine="MuJoCo C (native CCD, MPR, tight CCD, jaxenvs' surface collider) and MJX "
            "on the CPU",
            notes=f"{args.points} placements, seed {args.seed}, depth uniform in 0-12 mm",
        )
        results_io.write(args.json, rec)


if __name__ == "__main__":
    main()
