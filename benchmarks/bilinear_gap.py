"""How far ``bilinear_height`` is from MuJoCo's heightfield surface (``height``) on the
default terrain, per terrain type: 20,000 points per type (``--points``), each on a tile of
that type at a level drawn uniformly, uniform over the tile (``numpy`` seed ``--seed``).
Prints a markdown table of the max, the 99th percentile and the mean (mm)::

    JAX_PLATFORMS=cpu python benchmarks/bilinear_gap.py
"""

from __future__ import annotations

import argparse

import jax.numpy as jnp
import numpy as np

from jaxenvs.scenes.height import HeightField, bilinear_height, height
from jaxenvs.scenes.terrain import TYPES, TerrainConfig, generate


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=(__doc__ or "").splitlines()[0])
    parser.add_argument("--points", type=int, default=20_000)
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args(argv)
    terrain = generate(TerrainConfig())
    field = HeightField(*(jnp.asarray(x) for x in terrain.field()))
    rng = np.random.default_rng(args.seed)
    print("| type | max | 99th percentile | mean |\n| --- | --- | --- | --- |")
    for column, name in enumerate(TYPES):
        bounds = np.array(
            [
                terrain.tile_bounds(int(lv), column)
                for lv in rng.integers(terrain.levels, size=args.points)
            ]
        )
        u = rng.uniform(size=(args.points, 2))
        xy = bounds[:, [0, 2]] + u * (bounds[:, [1, 3]] - bounds[:, [0, 2]])
        xy = jnp.asarray(xy, jnp.float32)
        gap = 1000 * np.abs(np.asarray(height(field, xy)) - np.asarray(bilinear_height(field, xy)))
        p99 = np.percentile(gap, 99)
        print(f"| {name} | {gap.max():.1f} mm | {p99:.2f} mm | {gap.mean():.3f} mm |")


if __name__ == "__main__":
    main()
