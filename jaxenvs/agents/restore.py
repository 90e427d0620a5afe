"""Using a finished (or interrupted) run: its state, its greedy policy, its evaluation.

:func:`restore` loads a run directory's config and checkpoint (refusing one of another
env or algorithm); :func:`load_policy` gives the greedy policy of its best seed to other
tools (``jaxenvs view``/``render --policy``); :func:`evaluate_run` is ``jaxenvs eval``.
Each can step the env with another engine than the run's (``physics``).
"""

from __future__ import annotations

import json
from collections.abc import Callable
from pathlib import Path
from typing import Any

import jax
import numpy as np

from jaxenvs.agents import checkpoint
from jaxenvs.agents.base import Trainer
from jaxenvs.agents.evaluation import eval_key, make_evaluator
from jaxenvs.agents.results import write_policy_video
from jaxenvs.agents.run_config import (
    CHECKPOINT_FILE,
    SUMMARY_FILE,
    ResolvedConfig,
    build,
    load_run_config,
    seed_keys,
    with_physics,
)
from jaxenvs.core import Env

PyTree = Any


def restore(
    run_dir: str | Path, physics: str | None = None
) -> tuple[ResolvedConfig, Env, Trainer, PyTree]:
    """Config, env, trainer and the (seed-batched) runner state of a run directory;
    ``physics`` steps the env with another engine than the run's (cross-engine eval)."""
    resolved = with_physics(load_run_config(run_dir), physics)
    env, trainer = build(resolved)
    keys = seed_keys(resolved.train.seed, resolved.train.num_seeds)
    template = jax.eval_shape(jax.vmap(trainer.init), keys)
    path = Path(run_dir) / CHECKPOINT_FILE
    state, meta = checkpoint.load(path, template)
    expected = {"env_id": resolved.env_id, "algo": resolved.algo}
    checkpoint.check_matches(path, {k: meta.get(k) for k in expected}, expected)
    return resolved, env, trainer, state


def _best_seed(run_dir: Path, num_seeds: int) -> int:
    try:
        per_seed = json.loads((run_dir / SUMMARY_FILE).read_text())["eval_mean_return_per_seed"]
        return int(np.argmax(per_seed)) if len(per_seed) == num_seeds else 0
    except (OSError, ValueError, KeyError):
        return 0


def load_policy(
    run_dir: str | Path, physics: str | None = None
) -> tuple[str, Env, Callable[[jax.Array, jax.Array], jax.Array]]:
    """``(env_id, env, act_fn)`` of a run: ``act_fn(obs, key) -> action`` for ONE obs.

    The policy is the greedy policy of the seed with the best final evaluation (seed 0
    when there is no summary). ``act_fn`` is jittable and vmappable. ``physics`` builds
    the env with another engine than the run's.
    """
    resolved, env, trainer, state = restore(run_dir, physics)
    seed = _best_seed(Path(run_dir), resolved.train.num_seeds)
    params = jax.tree.map(lambda x: x[seed], jax.vmap(trainer.policy_params)(state))

    def act_fn(obs: jax.Array, key: jax.Array) -> jax.Array:
        return trainer.act(params, obs, key)

    return resolved.env_id, env, act_fn


def evaluate_run(
    run_dir: str | Path,
    episodes: int,
    seed: int | None = None,
    video: str | Path | None = None,
    physics: str | None = None,
) -> dict[str, Any]:
    """Greedy evaluation of every seed of a run from its checkpoint (and a video);
    ``physics`` evaluates under another engine than the one it trained on."""
    resolved, env, trainer, state = restore(run_dir, physics)
    k = resolved.train.seed + 1 if seed is None else seed
    params = jax.vmap(trainer.policy_params)(state)
    evaluate = jax.jit(jax.vmap(make_evaluator(env, trainer.act, episodes), in_axes=(0, None)))
    returns, trajectory, lengths = jax.device_get(evaluate(params, eval_key(k)))
    returns = np.asarray(returns)
    result = {
        "env_id": resolved.env_id,
        "algo": resolved.algo,
        "physics": env.physics,
        "episodes": int(returns.size),
        "mean_return": float(returns.mean()),
        "std_return": float(returns.std()),
        "mean_return_per_seed": returns.mean(axis=1).tolist(),
    }
    if video is not None:
        best = int(np.argmax(returns.mean(axis=1)))
        traj = jax.tree.map(lambda x: x[best], trajectory)
        msgs: list[str] = []
        written = write_policy_video(env, traj, int(lengths[best]), Path(video), msgs.append)
        result["video"] = str(written) if written else None
        if msgs:
            result["video_error"] = msgs[0]
    return result
