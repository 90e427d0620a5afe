"""A throughput sweep drawn: env steps/s against batch, log-log, peers as horizontal lines."""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

from jaxenvs import files
from jaxenvs.bench import MODES, is_ours
from jaxenvs.run.results import agg_pyplot


def plot(results: Sequence[dict[str, Any]], path: str) -> None:
    """Log-log env steps/s vs batch, one panel per task, peers as horizontal lines.

    ``results`` are :func:`jaxenvs.bench.time_runners`'s dicts (skipped peers are left
    out); the figure is written to ``path`` (PNG, or any format matplotlib knows).
    """
    plt = agg_pyplot()
    tasks = list(dict.fromkeys(r["task"] for r in results if not r.get("skipped")))
    fig, axes = plt.subplots(1, len(tasks), figsize=(5 * len(tasks), 4), squeeze=False)
    for ax, task in zip(axes[0], tasks, strict=True):
        rows = [r for r in results if r["task"] == task and not r.get("skipped")]
        _draw_ours(ax, rows)
        for i, r in enumerate(r for r in rows if not is_ours(r)):
            ax.axhline(
                r["env_steps_per_s"],
                ls="--",
                color=f"C{(i + 3) % 10}",
                label=f"{r['name']} {r['variant']} x{r['num_envs']}",
            )
        ax.set_xscale("log", base=2)
        ax.set_yscale("log")
        ax.set_xlabel("envs")
        ax.set_ylabel("env steps/s")
        ax.set_title(task)
        ax.legend(fontsize=6)
    fig.tight_layout()
    with files.atomic_path(path) as tmp:
        fig.savefig(tmp, dpi=120)
    plt.close(fig)


def _draw_ours(ax: Any, rows: Sequence[dict[str, Any]]) -> None:
    """One line per (mode, engine) of ours: env steps/s at each batch size."""
    for mode in MODES:
        for physics in ("mjx", "c"):
            pts = sorted(
                (r["num_envs"], r["env_steps_per_s"])
                for r in rows
                if is_ours(r) and r["variant"] == mode and r.get("physics", "mjx") == physics
            )
            if pts:
                ax.plot(*zip(*pts, strict=True), marker="o", label=f"jaxenvs {mode} ({physics})")
