"""The compiled programs of a run: init, chunk and evaluator, built once and stored.

:func:`build_programs` turns a resolved config into the jitted ``vmap``-over-seeds init
and chunk (split over a device mesh when there is more than one device) and the greedy
evaluator, compiled on a background thread. It is cached per config, and on one device
with the compile cache on, :func:`program_store` keeps the traced programs on disk, so a
warm start skips tracing as well as compiling.
"""

from __future__ import annotations

import concurrent.futures
import dataclasses
import functools
from collections.abc import Callable
from typing import Any

import jax

from jaxenvs import registry
from jaxenvs.agents.base import Trainer
from jaxenvs.core import Env
from jaxenvs.core.xla import jit
from jaxenvs.run import compile_cache, program_cache
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
    (:func:`jaxenvs.run.placement.mesh_programs`). On one device,
    with the compile cache on, init, chunk and evaluator are stored traced and loaded on
    later runs (:func:`program_store`), so a warm start skips most tracing as well as
    compiling.
    """
    env, trainer = build(resolved)
    mesh = run_mesh(resolved.agent.num_envs, env.physics, devices, env.c_envs_per_device)
    init_fn: Any = None
    chunk_fn: Any = None
    if mesh.size > 1:  # laid out over the mesh, the evaluator too (jaxenvs.run.placement)
        trainer, init_fn, chunk_fn, compile_evaluate = mesh_programs(resolved, env, trainer, mesh)
        return Programs(env, trainer, init_fn, chunk_fn, _COMPILER.submit(compile_evaluate))
    evaluator = make_evaluator(env, trainer.act, resolved.train.eval_episodes)
    keys = seed_keys(resolved.train.seed, resolved.train.num_seeds)
    key_shape = jax.eval_shape(lambda: eval_key(0))
    store = program_store(resolved, env, trainer) if mesh.size == 1 else None
    if store is not None:
        # the training state's structure, which the stored programs' outputs refer to
        # (~0.5 s of tracing init). init runs through the store too: a state made by a
        # plain jit would reach the chunk with other input shardings and compile it twice
        template = jax.eval_shape(jax.vmap(trainer.init), keys)
        init_fn = store(jax.vmap(trainer.init), (keys,), "init", (template,))
        chunk_fn = store(jax.vmap(trainer.chunk), (template,), "chunk", (template,))
        params_shape = jax.eval_shape(jax.vmap(trainer.policy_params), template)
        env_state = jax.eval_shape(env.reset, jax.random.key(0))  # the trajectory's structure

        def compile_evaluate() -> Any:
            evaluate = jax.vmap(evaluator, in_axes=(0, None))
            program = store(evaluate, (params_shape, key_shape), "eval", (env_state,))
            return program.jitted.lower(params_shape, key_shape).compile()

        return Programs(env, trainer, init_fn, chunk_fn, _COMPILER.submit(compile_evaluate))
    if mesh.size == 1:
        init_fn = jit(jax.vmap(trainer.init))
        chunk_fn = jit(jax.vmap(trainer.chunk))
    evaluate = jit(jax.vmap(evaluator, in_axes=(0, None)))
    params_shape = jax.eval_shape(jax.vmap(trainer.policy_params), init_fn.eval_shape(keys))
    future = _COMPILER.submit(lambda: evaluate.lower(params_shape, key_shape).compile())
    return Programs(env, trainer, init_fn, chunk_fn, future)


#: modules whose tasks and trainers may have their programs stored: the key covers the
#: package's own files only (see :mod:`jaxenvs.run.program_cache`).
STORE_MODULES: tuple[str, ...] = ("jaxenvs.",)


def program_store(
    resolved: ResolvedConfig, env: Env, trainer: Trainer
) -> Callable[..., program_cache.Program] | None:
    """Loads/stores traced programs next to the compile cache (``None``: not used).

    Used only while the compile cache is on and for tasks and trainers defined in this
    package, whose code the stored programs' keys cover (see :mod:`jaxenvs.run.program_cache`).
    """
    cache = compile_cache.active()
    factory = registry.spec(resolved.env_id).factory
    owners = (type(env).__module__, type(trainer).__module__, getattr(factory, "__module__", ""))
    if cache is None or not all(str(m).startswith(STORE_MODULES) for m in owners):
        return None
    # a stored (exported) program cannot carry a host callback: the C engine's programs
    # are stored only on its native path, and say so in their key
    path = getattr(getattr(env.sim, "engine", None), "path", None)
    if env.physics != "mjx" and path != "native":
        return None
    settings = resolved.to_dict()
    settings["c_engine"] = path
    settings["train"] = {k: v for k, v in settings["train"].items() if k != "seed"}

    def store(
        fn: Callable[..., Any], args: tuple[Any, ...], name: str, known: tuple[Any, ...]
    ) -> program_cache.Program:
        return program_cache.load_or_export(
            fn,
            args,
            name=f"{resolved.algo}-{resolved.env_id}-{name}",
            config=settings,
            directory=cache / program_cache.SUBDIR,
            known=known,
        )

    return store
