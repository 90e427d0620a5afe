"""The training runner behind ``jaxenvs train`` / ``eval`` / ``compare``; algorithm-agnostic.

This module only gathers the public names of the runner's rooms, so callers have one
place to import from:

* :mod:`jaxenvs.run.run_config`: the config file's sections, their resolution
  (:func:`resolve_config`), the algorithm table :data:`ALGORITHMS`, :func:`build`, and the
  names of a run directory's files.
* :mod:`jaxenvs.run.programs`: the compiled init, chunk and evaluator of a config,
  cached per config, and stored traced beside the compile cache
  (:mod:`jaxenvs.run.program_store`).
* :mod:`jaxenvs.run.loop`: :func:`train`, the chunk loop with its checkpoints, resume
  and Ctrl-C.
* :mod:`jaxenvs.run.results`: progress.csv, the progress bar, summary.json, the
  learning curve and the policy video.
* :mod:`jaxenvs.run.evaluation`: the greedy evaluator; :mod:`jaxenvs.run.restore`:
  a finished run's state, policy and evaluation.

A run directory holds ``config.yaml`` (fully resolved: every field of every section),
``progress.csv`` (one row per chunk and seed, with wall and process-CPU seconds),
``checkpoint.npz`` (written atomically after every chunk), ``summary.json``,
``learning_curve.png`` and, when rendering works, ``video.mp4``. The run itself:
``vmap(init)`` over ``num_seeds`` keys, then a Python loop over chunks of one jitted
``vmap(chunk)``; a chunk is a pure function of the runner state,
so resuming from the checkpoint after chunk ``i`` gives the same final state as a run
that never stopped.

A test that replaces one piece (say ``write_progress``) patches the module that looks it
up (:mod:`jaxenvs.run.loop`, :mod:`jaxenvs.run.programs`), not this one.
"""

from __future__ import annotations

from jaxenvs.run.evaluation import eval_key, make_evaluator
from jaxenvs.run.loop import RunState, train
from jaxenvs.run.programs import Programs, build_programs
from jaxenvs.run.restore import (
    POLICY_FILE,
    evaluate_run,
    load_policy,
    restore,
    restore_policy,
    save_policy,
)
from jaxenvs.run.results import learning_curve, plot_curves, read_progress
from jaxenvs.run.run_config import (
    ALGORITHMS,
    CHECKPOINT_FILE,
    CONFIG_FILE,
    CURVE_FILE,
    PROGRESS_FILE,
    SECTIONS,
    SUMMARY_FILE,
    VIDEO_FILE,
    AlgoEntry,
    ResolvedConfig,
    RunConfig,
    algorithm,
    build,
    engine_resolved,
    load_run_config,
    resolve_config,
    seed_keys,
    shipped_config,
    with_physics,
)
from jaxenvs.run.video import VIDEO_FPS, VIDEO_SIZE, write_policy_video

__all__ = [
    "ALGORITHMS",
    "CHECKPOINT_FILE",
    "CONFIG_FILE",
    "CURVE_FILE",
    "POLICY_FILE",
    "PROGRESS_FILE",
    "SECTIONS",
    "SUMMARY_FILE",
    "VIDEO_FILE",
    "VIDEO_FPS",
    "VIDEO_SIZE",
    "AlgoEntry",
    "Programs",
    "ResolvedConfig",
    "RunConfig",
    "RunState",
    "algorithm",
    "build",
    "build_programs",
    "engine_resolved",
    "eval_key",
    "evaluate_run",
    "learning_curve",
    "load_policy",
    "load_run_config",
    "make_evaluator",
    "plot_curves",
    "read_progress",
    "resolve_config",
    "restore",
    "restore_policy",
    "save_policy",
    "seed_keys",
    "shipped_config",
    "train",
    "with_physics",
    "write_policy_video",
]
