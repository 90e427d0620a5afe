"""Scale-out: env steps/s and PPO updates on one GPU against two."""

from __future__ import annotations

from .common import Cells, Rec, Row, Table, one, rate, rows

FILES = ("scaling_h200x2_reacher_walker",)
GPU_FILES = ("scaling_gpu",)
GPU4_FILES = ("scaling_gpu4",)
JOYSTICK_FILES = ("scaling_gpu4_joystick",)
JOYSTICK_SEEDS_FILES = ("scaling_gpu2_joystick_seeds",)
FIRST_CHUNK_FILES = ("first_chunk_h200",)
STAGED_FILES = ("first_chunk_staged_h200",)


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


def scaling_gpu(recs: list[Rec]) -> Cells:
    """PPO end to end per mode and GPU count (benchmarks/scaling.py), the env alone last."""
    (rec,) = recs
    cells = [["task", "mode", "GPUs", "envs", "env steps/s", "speed-up", "first chunk"]]
    for r in rec["rows"]:
        if r["mode"] == "env-only":
            ppo = f"PPO {r['ppo_over_env']:.2f}x of it"
            cells.append([r["task"], "env alone", "1", f"{r['num_envs_total']:,}",
                          rate(r["env_steps_per_s"]), ppo, "-"])  # fmt: skip
            continue
        cells.append(
            [
                r["task"],
                "one GPU" if r["gpus"] == 1 else r["mode"],
                str(r["gpus"]),
                f"{r['num_envs_total']:,}",
                rate(r["env_steps_per_s"]),
                f"**{r['speedup']:.2f}x**",
                f"{r['first_chunk_s']:.1f} s",
            ]
        )
    return cells


def first_chunk(recs: list[Rec]) -> Cells:
    """The first chunk of each process (after init) and the time from the start of the
    build to its end, with the rate of the chunk after it."""
    (rec,) = recs
    cells = [["process", "first chunk (trace, compile, run)", "build to first chunk's end",
              "env steps/s after it"]]  # fmt: skip
    for r in rec["rows"]:
        cells.append(
            [
                str(r["run"]),
                f"**{r['first_chunk_s']:.1f} s**",
                f"{r['to_first_chunk_s']:.1f} s",
                rate(r["env_steps_per_s"]),
            ]
        )
    return cells


def first_chunk_staged(recs: list[Rec]) -> Cells:
    """The first chunk of each process, in the order they ran, by how the chunk ran."""
    (rec,) = recs
    cells = [["process", "chunk", "first chunk (after init)", "build to first chunk's end",
              "env steps/s after it"]]  # fmt: skip
    for r in rec["rows"]:
        how = "its stages' programs" if r["chunk"] == "staged" else "one program"
        cells.append(
            [
                str(r["run"]),
                how,
                f"**{r['first_chunk_s']:.1f} s**",
                f"{r['to_first_chunk_s']:.1f} s",
                rate(r["env_steps_per_s"]),
            ]
        )
    return cells


TABLES = {
    "scaling-env": Table(FILES, scaling_env),
    "scaling-ppo": Table(FILES, scaling_ppo),
    "scaling-gpu": Table(GPU_FILES, scaling_gpu),
    "scaling-gpu4": Table(GPU4_FILES, scaling_gpu),
    "scaling-gpu4-joystick": Table(JOYSTICK_FILES, scaling_gpu),
    "scaling-gpu2-joystick-seeds": Table(JOYSTICK_SEEDS_FILES, scaling_gpu),
    "first-chunk-h200": Table(FIRST_CHUNK_FILES, first_chunk),
    "first-chunk-staged-h200": Table(STAGED_FILES, first_chunk_staged),
}
