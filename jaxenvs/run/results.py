"""A run's results: progress.csv, the progress bar, summary.json and plots (the video is
:mod:`jaxenvs.run.video`'s).

Everything here reads or writes the files of a run directory (names in
:mod:`jaxenvs.run.run_config`) or shows a run's figures; nothing runs training.
"""

from __future__ import annotations

import csv
import json
import math
import sys
import threading
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import jax
import numpy as np
import yaml

from jaxenvs import files
from jaxenvs.agents.base import CHUNK_METRICS
from jaxenvs.core import State
from jaxenvs.run.run_config import CONFIG_FILE, PROGRESS_FILE

#: the task metric of a curriculum's level (``info["level"]``, per env): a run of a task
#: that reports it gets each chunk's mean level in progress.csv, the bar and the plot
LEVEL = "level"


# ----------------------------------------------------------------------- progress I/O
def metric_columns(metric_shapes: Mapping[str, Any]) -> list[str]:
    """progress.csv's columns: the common chunk metrics, then a trainer's own per-seed
    scalars (sorted), then the evaluation and the timings."""
    extra = sorted(
        k for k, v in metric_shapes.items() if k not in CHUNK_METRICS and len(v.shape) == 1
    )
    return ["chunk", "seed", *CHUNK_METRICS, *extra, "eval_return", "wall_seconds", "cpu_seconds"]


def task_level(runner_state: Any) -> np.ndarray | None:
    """Each seed's mean curriculum level over its envs (float64, ``(num_seeds,)``): the
    :data:`LEVEL` metric of the env state in ``runner_state`` (the first
    :class:`~jaxenvs.core.State` in it, leading axes seeds then envs); ``None`` when it
    holds no such state or the task reports no level."""
    leaves = jax.tree.leaves(runner_state, is_leaf=lambda x: isinstance(x, State))
    state = next((x for x in leaves if isinstance(x, State)), None)
    if state is None or LEVEL not in state.info:
        return None
    level = np.asarray(jax.device_get(state.info[LEVEL]), np.float64)
    return level.reshape(level.shape[0], -1).mean(axis=1) if level.ndim else level[None]


def read_progress(path: Path) -> list[dict[str, str]]:
    """progress.csv's rows as strings (none when the file is missing)."""
    if not path.is_file():
        return []
    with path.open(newline="") as f:
        return list(csv.DictReader(f))


def write_progress(path: Path, columns: list[str], rows: list[dict[str, Any]]) -> None:
    """Replace progress.csv atomically with ``rows``."""
    with files.atomic_path(path) as tmp, tmp.open("w", newline="") as f:
        writer = csv.DictWriter(f, columns, extrasaction="ignore")
        writer.writeheader()
        writer.writerows(rows)


def format_value(x: Any) -> str:
    """A scalar as progress.csv writes it: floats to 6 significant digits, ``nan``."""
    x = np.asarray(x).item()
    if isinstance(x, float):
        return "nan" if math.isnan(x) else f"{x:.6g}"
    return str(x)


def write_json(path: Path, data: Mapping[str, Any]) -> None:
    """Write ``data`` as indented JSON, atomically."""
    files.write_text(path, json.dumps(data, indent=2, allow_nan=True) + "\n")


# ----------------------------------------------------------------------- progress bar
class ProgressBar:
    """tqdm bar over env steps, or nothing when quiet / not a terminal."""

    def __init__(self, total: int, initial: int, quiet: bool, desc: str) -> None:
        self.bar = None
        if not quiet and sys.stderr.isatty():
            from tqdm import tqdm

            self.bar = tqdm(total=total, initial=initial, desc=desc, unit="step", smoothing=0.3)

    def update(self, steps: int, postfix: dict[str, str]) -> None:
        if self.bar is not None:
            self.bar.update(steps)
            self.bar.set_postfix(postfix, refresh=True)

    def close(self) -> None:
        if self.bar is not None:
            self.bar.close()


def _rate_key(metrics: Mapping[str, Any]) -> str | None:
    for key in ("epsilon", "learning_rate", "lr"):
        if key in metrics:
            return key
    return None


def progress_postfix(metrics: Mapping[str, Any], seconds: float, steps: int) -> dict[str, str]:
    """The progress bar's figures of a chunk of ``steps`` env steps (all seeds)."""
    postfix = {
        "ep/s": f"{float(np.sum(metrics['episodes_in_chunk'])) / seconds:.0f}",
        "steps/s": f"{steps / seconds:.3g}",
        "return": f"{np.nanmean(metrics['mean_return']):.1f}"
        if np.any(np.isfinite(metrics["mean_return"]))
        else "-",
    }
    rk = _rate_key(metrics)
    if rk is not None:
        postfix[rk] = f"{float(np.mean(metrics[rk])):.3g}"
    if LEVEL in metrics:
        postfix[LEVEL] = f"{float(np.mean(metrics[LEVEL])):.2f}"
    return postfix


# ------------------------------------------------------------------ summary and video
def summarize(
    rows: list[dict[str, Any]],
    eval_returns: np.ndarray,
    top: np.ndarray,
    wall: float,
    chunks: int,
    num_chunks: int,
    finished: bool,
) -> dict[str, Any]:
    """summary.json's figures: the final evaluation, steps and episodes, and the course's
    overall (mean episode length over the run) and best-100 scores, per seed and over
    all; ``top`` holds each seed's longest episode lengths (-1 padded)."""
    num_seeds = eval_returns.shape[0]
    per_seed_steps, per_seed_eps, overall = [], [], []
    for k in range(num_seeds):
        mine = [r for r in rows if int(r["seed"]) == k]
        steps = int(float(mine[-1]["env_steps"])) if mine else 0
        eps = int(float(mine[-1]["episodes"])) if mine else 0
        total_len = sum(
            float(r["mean_length"]) * float(r["episodes_in_chunk"])
            for r in mine
            if r["mean_length"] not in ("nan", "") and float(r["episodes_in_chunk"]) > 0
        )
        per_seed_steps.append(steps)
        per_seed_eps.append(eps)
        overall.append(total_len / eps if eps else math.nan)
    best100 = [float(np.mean(t[t >= 0][:100])) if np.any(t >= 0) else math.nan for t in top]
    return {
        "eval_mean_return": float(eval_returns.mean()),
        "eval_std_return": float(eval_returns.std()),
        "eval_mean_return_per_seed": eval_returns.mean(axis=1).tolist(),
        "eval_episodes": int(eval_returns.size),
        "env_steps": int(sum(per_seed_steps)),
        "env_steps_per_seed": per_seed_steps,
        "episodes": int(sum(per_seed_eps)),
        "wall_seconds": round(wall, 3),
        "overall_score": float(np.nanmean(overall)) if num_seeds else math.nan,
        "overall_score_per_seed": overall,
        "best_100_score": float(np.nanmean(best100)) if top.size else None,
        "best_100_score_per_seed": best100 if top.size else None,
        "chunks": chunks,
        "num_chunks": num_chunks,
        "finished": finished,
        "num_seeds": num_seeds,
    }


# ------------------------------------------------------------------------------ plots
def learning_curve(
    run_dir: str | Path, column: str = "mean_return"
) -> tuple[np.ndarray, np.ndarray]:
    """``(env_steps per chunk, column (chunks, seeds))`` from a run's progress.csv (NaN
    where a row lacks the column): ``mean_return`` by default."""
    rows = read_progress(Path(run_dir) / PROGRESS_FILE)
    if not rows:
        raise ValueError(f"{run_dir}: no progress recorded yet ({PROGRESS_FILE})")
    chunks = sorted({int(r["chunk"]) for r in rows})
    seeds = sorted({int(r["seed"]) for r in rows})
    index = {(int(r["chunk"]), int(r["seed"])): r for r in rows}
    steps = np.zeros(len(chunks))
    ret = np.full((len(chunks), len(seeds)), np.nan)
    for i, c in enumerate(chunks):
        for j, s in enumerate(seeds):
            r = index.get((c, s))
            if r is None:
                continue
            value = r.get(column)
            ret[i, j] = float(value) if value not in (None, "") else math.nan
            steps[i] = max(steps[i], float(r["env_steps"]))
    return steps, ret


def agg_pyplot() -> Any:
    """``matplotlib.pyplot`` on the Agg backend (imported on first use): what every
    figure jaxenvs writes to a file draws with."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def preload_plotting() -> threading.Thread:
    """Import what :func:`plot_curves` needs (about 0.5 s of CPU on 2 cores, more on a
    fresh install, where matplotlib builds its font cache) on a daemon thread, started
    now: a training run calls this as its chunks start, when the host mostly waits on
    the compiled program, so the import is off the run's last seconds. Harmless to call
    more than once. A failed import is left to :func:`plot_curves` to report."""
    thread = threading.Thread(target=_preload, name="preload-pyplot", daemon=True)
    thread.start()
    return thread


def _preload() -> None:
    try:
        agg_pyplot()
    except Exception:  # noqa: BLE001 - plot_curves imports again and reports the failure
        return


def plot_curves(run_dirs: list[Path], out: str | Path, labels: list[str] | None = None) -> Path:
    """Return vs env steps of each run: every seed thin, the mean bold, min-max shaded;
    a run with a curriculum adds its mean :data:`LEVEL` (over seeds), dashed, on a second
    axis."""
    plt = agg_pyplot()

    fig, ax = plt.subplots(figsize=(7, 4.5))
    levels = None
    for i, run_dir in enumerate(run_dirs):
        steps, ret = learning_curve(run_dir)
        label = labels[i] if labels else _run_label(Path(run_dir))
        color = f"C{i}"
        if ret.shape[1] > 1:
            ax.plot(steps, ret, color=color, alpha=0.25, linewidth=0.8)
            with np.errstate(all="ignore"):
                lo, hi = np.nanmin(ret, axis=1), np.nanmax(ret, axis=1)
            ax.fill_between(steps, lo, hi, color=color, alpha=0.15)
        with np.errstate(all="ignore"):
            mean = np.nanmean(ret, axis=1) if ret.shape[1] else ret
        ax.plot(steps, mean, color=color, linewidth=2, label=f"{label} ({_seeds(ret.shape[1])})")
        level = learning_curve(run_dir, LEVEL)[1]
        if np.isfinite(level).any():
            levels = levels if levels is not None else ax.twinx()
            with np.errstate(all="ignore"):
                levels.plot(steps, np.nanmean(level, axis=1), color=color, linestyle="--")
    if levels is not None:
        levels.set_ylabel("mean curriculum level (dashed)")
    ax.set_xlabel("env steps")
    ax.set_ylabel("mean episode return (per chunk)")
    ax.grid(alpha=0.3)
    ax.legend(loc="best", fontsize=8)
    fig.tight_layout()
    out = Path(out)
    with files.atomic_path(out) as tmp:
        fig.savefig(tmp, dpi=100)
    plt.close(fig)
    return out


def _seeds(n: int) -> str:
    return f"{n} seed" if n == 1 else f"{n} seeds"


def _run_label(run_dir: Path) -> str:
    try:
        cfg = yaml.safe_load((run_dir / CONFIG_FILE).read_text())
        return f"{cfg['algo']} {cfg['env']['id']} ({run_dir.name})"
    except (OSError, yaml.YAMLError, KeyError, TypeError):
        return run_dir.name
