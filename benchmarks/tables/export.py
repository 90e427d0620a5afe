"""Export: the exported policies' actions beside the JAX policy's, per shipped config."""

from __future__ import annotations

from .common import Cells, Rec, Table, met, one


def export_parity(recs: list[Rec]) -> Cells:
    cells = [
        ["id", "training", "actor, obs normalised", "rollout obs", "max abs diff ONNX / npz"]
        + ["differing actions ONNX / npz", "passed"]
    ]
    for rec in recs:
        for env_id, training in dict.fromkeys((r["env_id"], r["training"]) for r in rec["rows"]):
            o, n = (one(rec, env_id=env_id, training=training, format=f) for f in ("onnx", "npz"))
            actor = "x".join(map(str, o["actor_hidden"]))
            cells.append(
                [
                    env_id,
                    f"{training}, {o['env_steps_trained']:,} steps",
                    f"{actor}, {'yes' if o['normalize_obs'] else 'no'}",
                    f"{o['observations']:,}",
                    f"{o['max_abs_diff']:.1e} / {n['max_abs_diff']:.1e}",
                    f"{o['mismatches']} / {n['mismatches']}",
                    met(o["passed"] and n["passed"]),
                ]
            )
    return cells


TABLES = {
    "export-parity": Table(("export_parity_cpu2", "export_parity_h200_walker"), export_parity),
}
