"""Using a finished (or interrupted) run: its state, its greedy policy, its evaluation.

:func:`restore` loads a run directory's config and checkpoint (refusing one of another
env or algorithm); :func:`restore_policy` the agent's parameters alone;
:func:`load_policy` gives the greedy policy of its best seed to other tools
(``jaxenvs view``/``render --policy``); :func:`evaluate_run` is ``jaxenvs eval``.

A checkpoint holds the whole runner state, the env batch's physics state included, and
that state's structure depends on the engine (MuJoCo's C engine leaves placeholders where
MJX holds arrays). It is therefore always read with the structure of the engine the run
trained under (its ``config.yaml``). What a policy needs (network and observation
normaliser, or Q-table) does not depend on the engine, so :func:`restore_policy`,
:func:`load_policy` and :func:`evaluate_run` can step the env with another engine than the
run's (``physics``); a resume cannot, and keeps the run's engine.
"""

from __future__ import annotations

import json
from collections.abc import Callable
from pathlib import Path
from typing import Any

import jax
import numpy as np

from jaxenvs.agents.base import Trainer
from jaxenvs.core import Env
from jaxenvs.core.xla import jit
from jaxenvs.run import checkpoint
from jaxenvs.run.evaluation import eval_key, make_evaluator
from jaxenvs.run.run_config import (
    CHECKPOINT_FILE,
    SUMMARY_FILE,
    ResolvedConfig,
    build,
    engine_resolved,
    load_run_config,
    seed_keys,
    with_physics,
)
from jaxenvs.run.video import write_policy_video

PyTree = Any
#: a run directory's greedy policy alone (:func:`save_policy`)
POLICY_FILE = "policy.npz"


def restore(run_dir: str | Path) -> tuple[ResolvedConfig, Env, Trainer, PyTree]:
    """Config, env, trainer and the (seed-batched) runner state of a run directory, under
    the engine the run trained with."""
    resolved = engine_resolved(load_run_config(run_dir))
    env, trainer = build(resolved)
    keys = seed_keys(resolved.train.seed, resolved.train.num_seeds)
    template = jax.eval_shape(jax.vmap(trainer.init), keys)
    path = Path(run_dir) / CHECKPOINT_FILE
    state, meta = checkpoint.load(path, template)
    expected = {"env_id": resolved.env_id, "algo": resolved.algo}
    checkpoint.check_matches(path, {k: meta.get(k) for k in expected}, expected)
    return resolved, env, trainer, state


def restore_policy(
    run_dir: str | Path, physics: str | None = None
) -> tuple[ResolvedConfig, Env, Trainer, PyTree]:
    """Config, env, trainer and the (seed-batched) policy parameters of a run directory.

    The parameters come from the checkpoint read under the run's own engine, or, in a run
    directory that keeps only its greedy policy (:data:`POLICY_FILE`, written by
    :func:`save_policy`; a GPU run brought home without its envs' states), from that file,
    as one seed. The config, env and trainer step with ``physics`` when given (``None``:
    the run's engine), so a policy trained under one engine is evaluated or rendered under
    the other.
    """
    run_dir = Path(run_dir)
    if not (run_dir / CHECKPOINT_FILE).exists() and (run_dir / POLICY_FILE).exists():
        trained = engine_resolved(load_run_config(run_dir))
        env, trainer = build(trained)
        template = jax.eval_shape(
            lambda k: trainer.policy_params(trainer.init(k)), jax.random.key(0)
        )
        one, _ = checkpoint.load(run_dir / POLICY_FILE, template)
        params = jax.tree.map(lambda x: x[None], one)
    else:
        trained, env, trainer, state = restore(run_dir)
        params = jax.vmap(trainer.policy_params)(state)
    resolved = with_physics(trained, physics)
    if resolved != trained:
        env, trainer = build(resolved)
    return resolved, env, trainer, params


def save_policy(run_dir: str | Path) -> Path:
    """Write the greedy policy of a run's best seed to ``run_dir/POLICY_FILE`` (a few
    hundred kB; the checkpoint also holds every training env's state) and return its
    path. A run directory holding it and its ``config.yaml`` can be evaluated, rendered,
    viewed and exported without its checkpoint."""
    run_dir = Path(run_dir)
    resolved, _, trainer, state = restore(run_dir)
    seed = _best_seed(run_dir, resolved.train.num_seeds)
    params = jax.tree.map(lambda x: x[seed], jax.vmap(trainer.policy_params)(state))
    checkpoint.save(run_dir / POLICY_FILE, params, {"seed_index": seed})
    return run_dir / POLICY_FILE


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
    resolved, env, trainer, params = restore_policy(run_dir, physics)
    seeds = jax.tree.leaves(params)[0].shape[0]
    seed = _best_seed(Path(run_dir), resolved.train.num_seeds) if seeds > 1 else 0
    params = jax.tree.map(lambda x: x[seed], params)

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
    resolved, env, trainer, params = restore_policy(run_dir, physics)
    k = resolved.train.seed + 1 if seed is None else seed
    evaluate = jit(jax.vmap(make_evaluator(env, trainer.act, episodes), in_axes=(0, None)))
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
