"""Scale-out: env steps/s and PPO updates on one GPU against two."""

from __future__ import annotations

from .common import Cells, Rec, Row, Table, one, rate, rows

FILES = ("scaling_h200x2_reacher_walker",)


def _per_call(r: Row) -> str:
    call = r["median_call_s"]
    return f"{call * 1e3:.1f} ms/call" if call < 1 else f"{call:.2f} s/call"


def scaling_env(recs: list[Rec]) -> Cells:
    (rec,) = recs
    cells = [["task", "1 GPU", "2 GPUs, same envs (strong)", "2 GPUs, 2x envs (weak)"]]
    for task in dict.fromkeys(r["task"] for r in rec["rows"]):
        base = one(rec, kind="env", task=task, devices=1)
        strong = one(rec, kind="env", task=task, devices=2, scheme="strong")
        weak = one(rec, kind="env", task=task, devices=2, scheme="weak")
        cells.append(
            [
                task,
                f"{rate(base['env_steps_per_s'])} at {base['num_envs']:,} envs ({_per_call(base)})",
                f"{rate(strong['env_steps_per_s'])}: **{strong['speedup']:.2f}x**",
                f"{rate(weak['env_steps_per_s'])} at {weak['num_envs']:,}: "
                f"**{weak['speedup']:.2f}x**",
            ]
        )
    return cells


def scaling_ppo(recs: list[Rec]) -> Cells:
    (rec,) = recs

    def cell(r: Row) -> str:
        per = r["median_call_s"] / r["updates_per_call"]
        return f"{per * 1e3:.1f} ms, {rate(r['env_steps_per_s'])}"

    cells = [["task", "1 GPU: per update, env steps/s", "2 GPUs", "speed-up"]]
    for task in dict.fromkeys(r["task"] for r in rows(rec, kind="ppo")):
        a = one(rec, kind="ppo", task=task, devices=1)
        b = one(rec, kind="ppo", task=task, devices=2)
        cells.append([task, cell(a), cell(b), f"**{b['speedup']:.2f}x**"])
    return cells


TABLES = {
    "scaling-env": Table(FILES, scaling_env),
    "scaling-ppo": Table(FILES, scaling_ppo),
}
