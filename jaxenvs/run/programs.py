"""The compiled programs of a run: init, chunk and evaluator, built once per config.

:func:`build_programs` turns a resolved config into the jitted ``vmap``-over-seeds init
and chunk (split over a device mesh when there is more than one device) and the greedy
evaluator, compiled on a background thread. It is cached per config; across processes,
JAX's persistent compile cache (:mod:`jaxenvs.run.compile_cache`) skips the compiles.
"""

from __future__ import annotations

import concurrent.futures
import dataclasses
import functools
from typing import Any

import jax

from jaxenvs.agents.base import Trainer
from jaxenvs.core import Env
from jaxenvs.core.xla import jit
from jaxenvs.physics.figures import figures_for
from jaxenvs.run.evaluation import eval_key, make_evaluator
from jaxenvs.run.placement import mesh_programs, run_mesh
from jaxenvs.run.run_config import ResolvedConfig, build, seed_keys

PyTree = Any

_COMPILER = concurrent.futures.ThreadPoolExecutor(1, thread_name_prefix="jaxenvs-compile")


@dataclasses.dataclass(frozen=True)
class Programs:
    """A run's env and trainer with its jitted init and chunk (``vmap``-ed over seeds)
    and the evaluator being compiled (``eval_future``)."""

    env: Env
    trainer: Trainer
    init_fn: Any
    chunk_fn: Any
    eval_future: concurrent.futures.Future

    def evaluate(self, params: PyTree, key: jax.Array) -> Any:
        """The evaluator's ``(returns, trajectory, length)`` of every seed (waits for
        its compile)."""
        return self.eval_future.result()(params, key)


@functools.lru_cache(maxsize=4)
def build_programs(resolved: ResolvedConfig, devices: int | None = None) -> Programs:
    """Env, trainer, the jitted ``vmap``s of init and chunk, and the evaluator.

    The evaluator is compiled ahead of time on a background thread while the caller
    compiles and runs the training chunks (XLA compiles one program per core, so on a
    small machine this hides most of the evaluator's compile). Cached per config, so a
    resume or a second run in the same process reuses the compiled programs. Over more
    than one device (``devices``; ``None``: :func:`jaxenvs.run.placement.run_mesh`),
    init and chunk split the env batch over a mesh of them
    (:func:`jaxenvs.run.placement.mesh_programs`).
    """
    env, trainer = build(resolved)
    mesh = run_mesh(
        resolved.agent.num_envs, env.physics, devices, figures_for(type(env)).c_envs_per_device
    )
    init_fn: Any  # jitted: ``eval_shape`` and ``lower`` below
    chunk_fn: Any
    if mesh.size > 1:  # laid out over the mesh, the evaluator too (jaxenvs.run.placement)
        trainer, init_fn, chunk_fn, compile_evaluate = mesh_programs(resolved, env, trainer, mesh)
        return Programs(env, trainer, init_fn, chunk_fn, _COMPILER.submit(compile_evaluate))
    init_fn, chunk_fn = jit(jax.vmap(trainer.init)), jit(jax.vmap(trainer.chunk))
    evaluator = make_evaluator(env, trainer.act, resolved.train.eval_episodes)
    keys = seed_keys(resolved.train.seed, resolved.train.num_seeds)
    key_shape = jax.eval_shape(lambda: eval_key(0))
    evaluate = jit(jax.vmap(evaluator, in_axes=(0, None)))
    params_shape = jax.eval_shape(jax.vmap(trainer.policy_params), init_fn.eval_shape(keys))
    future = _COMPILER.submit(lambda: evaluate.lower(params_shape, key_shape).compile())
    return Programs(env, trainer, init_fn, chunk_fn, future)
