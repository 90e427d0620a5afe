"""The compiled programs of a run: init, chunk and evaluator, built once per config.

:func:`build_programs` turns a resolved config into the jitted init and chunk over seeds
(split over a device mesh when there is more than one device) and the greedy evaluator,
compiled on a background thread once the first chunk has compiled. On an accelerator a
trainer's chunk that comes in stages runs as their programs (:class:`StagedChunk`), whose
compiles overlap. It is cached per config; across processes, JAX's persistent compile
cache (:mod:`jaxenvs.run.compile_cache`) skips the compiles, and where it is on, a run on
one device whose chunk is one program keeps its three programs traced beside it
(:mod:`jaxenvs.run.program_store`, :func:`program_store_for`), so that a later run skips
tracing them too.
"""

from __future__ import annotations

import concurrent.futures
import dataclasses
import functools
import threading
from collections.abc import Callable
from typing import Any

import jax
import jax.numpy as jnp

from jaxenvs import registry
from jaxenvs.agents.base import Stages, Trainer
from jaxenvs.core import Env
from jaxenvs.core.xla import jit, jit_once
from jaxenvs.physics.figures import figures_for
from jaxenvs.run import compile_cache, program_store
from jaxenvs.run.evaluation import eval_key, make_evaluator
from jaxenvs.run.placement import mesh_programs, run_mesh
from jaxenvs.run.run_config import ALGORITHMS, ResolvedConfig, build, seed_keys

PyTree = Any

#: two threads: a staged chunk's two compiles side by side (the evaluator's comes later)
_COMPILER = concurrent.futures.ThreadPoolExecutor(2, thread_name_prefix="jaxenvs-compile")


class BackgroundCompile:
    """``compile()`` run once on a background compile thread, when first asked for."""

    def __init__(self, compile: Callable[[], Any]) -> None:
        self._compile = compile
        self._lock = threading.Lock()
        self._future: concurrent.futures.Future | None = None

    def start(self) -> concurrent.futures.Future:
        """The compile's future, submitting it on the first call."""
        with self._lock:
            if self._future is None:
                self._future = _COMPILER.submit(self._compile)
            return self._future


@dataclasses.dataclass(frozen=True)
class Programs:
    """A run's env and trainer with its jitted init and chunk (over seeds) and its
    evaluator, compiled on a background thread from :meth:`start_evaluator` on."""

    env: Env
    trainer: Trainer
    init_fn: Any
    chunk_fn: Any
    evaluator: BackgroundCompile

    def start_chunk(self, state: PyTree) -> None:
        """Start compiling the chunk for states like ``state`` on the background threads
        where it has a ``start`` (:meth:`StagedChunk.start`, :meth:`BackgroundChunk.start`);
        a chunk without one (over a mesh) is compiled by its first call."""
        start = getattr(self.chunk_fn, "start", None)
        if start is not None:
            start(state)

    def start_evaluator(self) -> None:
        """Start the evaluator's compile on a background thread (once; the run loop
        calls it when the first chunk's call has returned, i.e. has compiled, so that the
        two programs' tracing and compiling do not share the machine)."""
        self.evaluator.start()

    def evaluate(self, params: PyTree, key: jax.Array) -> Any:
        """The evaluator's ``(returns, trajectory, length)`` of every seed (starts its
        compile if nothing has, and waits for it)."""
        return self.evaluator.start().result()(params, key)


class StagedChunk:
    """A trainer's chunk over seeds run as the programs of its :class:`Stages`: ``count``
    times the rollout's (``collect``) then the learning's, then ``finish``'s. Called like
    the jitted chunk (``chunk(state) -> (state, metrics)``, and ``eval_shape``).

    The three compile apart on the two background compile threads (:meth:`start`), the
    rollout's on one and the learning's and ``finish``'s on the other, from when the run
    loop starts them, after their traces (``eval_shape``) and before ``init`` compiles and
    runs; the first call waits for them. A process exits only once compiles it started
    have ended. As one program the walker's chunk compiled in 28.5 s on one H200; apart,
    its rollout in 21.9 s and its learning in 6.8 s. The computation is the chunk's
    (:func:`chunk_of`); XLA compiles other programs, so on an accelerator its bits may
    differ from the chunk as one program (on a CPU the tests find them equal under the
    C engine but for the last bit of a weight on some processors, and within 1e-3 under
    MJX). It launches two programs per update
    and one to finish (17 a chunk for the walker's 8 updates), which an accelerator queues
    behind the running one.
    """

    def __init__(self, stages: Stages, num_seeds: int) -> None:
        self._count = stages.count
        self._collect = jit(over_seeds(stages.collect, num_seeds))
        self._learn = jit(over_seeds(stages.learn, num_seeds))
        self._finish = jit(over_seeds(_over_stacked(stages.finish), num_seeds))
        self._compiles = _Compiles()

    def eval_shape(self, state: PyTree) -> tuple[PyTree, dict[str, Any]]:
        """The shapes of ``self(state)``, from each program's trace."""
        state, batch = self._collect.eval_shape(state)
        state, metrics = self._learn.eval_shape(state, batch)
        return state, self._finish.eval_shape(state, (metrics,) * self._count)

    def start(self, state: PyTree) -> None:
        """Start compiling the programs for states like ``state`` (arrays or their
        ``eval_shape``), once: the rollout's on one background compile thread, the
        learning's and ``finish``'s on the other. The run loop starts it before ``init``
        runs; the first call starts it if nothing has."""
        self._started(state)

    def _started(self, state: PyTree) -> tuple[concurrent.futures.Future, ...]:
        def submit() -> tuple[concurrent.futures.Future, ...]:
            rollout = _COMPILER.submit(lambda: self._collect.trace(state).lower().compile())
            return rollout, _COMPILER.submit(self._compile_rest, state)

        return self._compiles.start(submit)

    def _compile_rest(self, state: PyTree) -> tuple[Any, Any]:
        state, batch = self._collect.eval_shape(state)
        learn = self._learn.trace(state, batch)
        state, metrics = learn.out_info
        finish = self._finish.trace(state, (metrics,) * self._count)
        return learn.lower().compile(), finish.lower().compile()

    def compiled(self, state: PyTree) -> tuple[Any, Any, Any]:
        """The compiled rollout, learning and finish (starting their compile if nothing
        has, and waiting for it). A compile's error is raised, and the next call starts
        the compiles again; an interrupted wait leaves the compiles running."""
        rollout, rest = self._started(state)
        return (rollout.result(), *rest.result())

    def __call__(self, state: PyTree) -> tuple[PyTree, dict[str, Any]]:
        collect, learn, finish = self.compiled(state)
        metrics = []
        for _ in range(self._count):
            state, batch = collect(state)
            state, m = learn(state, batch)
            metrics.append(m)
        return state, finish(state, tuple(metrics))


class BackgroundChunk:
    """A chunk that is one program (jitted, or loaded from the program store), compiled
    on a background compile thread from :meth:`start` on. Called like the jitted chunk
    (``chunk(state) -> (state, metrics)``, and ``eval_shape``).

    The run loop starts it before ``init`` compiles and runs, as a :class:`StagedChunk`'s,
    so that the chunk's compile, or its load from JAX's compile cache, overlaps init's
    and the run's first checkpoint instead of following them; the first call waits for
    it. It is compiled and called without weak types
    (:func:`jaxenvs.run.program_store.strong`), so that a state whose leaves' weak types
    differ from the first one's runs the same program. The compile thread sees JAX's
    global settings only: the program is compiled for the default device, and a state
    must live there (one device's run).
    """

    def __init__(self, chunk: Callable[..., Any]) -> None:
        #: the chunk it compiles: a jitted function or a stored program
        self.chunk = chunk
        self._compiles = _Compiles()

    def eval_shape(self, state: PyTree) -> Any:
        """The shapes of ``self(state)``, from the chunk's trace."""
        return self.chunk.eval_shape(state)  # type: ignore[attr-defined]

    def start(self, state: PyTree) -> None:
        """Start compiling the chunk for states like ``state`` (arrays or their
        ``eval_shape``) on a background compile thread, once; again after a compile
        that failed."""
        self._started(state)

    def _started(self, state: PyTree) -> tuple[concurrent.futures.Future, ...]:
        def submit() -> tuple[concurrent.futures.Future, ...]:
            shapes = jax.tree.map(lambda x: jax.ShapeDtypeStruct(x.shape, x.dtype), state)
            return (_COMPILER.submit(self._compile, shapes),)

        return self._compiles.start(submit)

    def _compile(self, shapes: PyTree) -> Any:
        return self.chunk.lower(shapes).compile()  # type: ignore[attr-defined]

    def compiled(self, state: PyTree) -> Any:
        """The compiled chunk (starting its compile if nothing has, and waiting for it).
        A compile's error is raised, and the next call starts the compile again; an
        interrupted wait leaves the compile running."""
        (future,) = self._started(state)
        return future.result()

    def __call__(self, state: PyTree) -> tuple[PyTree, dict[str, Any]]:
        return self.compiled(state)(jax.tree.map(program_store.strong, state))


class _Compiles:
    """A chunk's compiles on the background compile threads: submitted together once,
    and again once one of them has failed (an error, or cancelled); a wait for them that
    is interrupted leaves them running."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._futures: tuple[concurrent.futures.Future, ...] = ()

    def start(
        self, submit: Callable[[], tuple[concurrent.futures.Future, ...]]
    ) -> tuple[concurrent.futures.Future, ...]:
        """The compiles' futures: ``submit()``'s (which submits them) on the first call
        and after a failure, else those submitted before."""
        with self._lock:
            if not self._futures or any(map(_failed, self._futures)):
                self._futures = submit()
            return self._futures


def _failed(future: concurrent.futures.Future) -> bool:
    """Whether ``future`` ended without a result (an error, or cancelled)."""
    return future.done() and (future.cancelled() or future.exception() is not None)


def _over_stacked(finish: Callable[[PyTree, Any], Any]) -> Callable[[PyTree, Any], Any]:
    """``finish`` of a tuple of updates' metrics, stacked along a new leading axis."""

    def stacked(state: PyTree, metrics: tuple[Any, ...]) -> Any:
        return finish(state, jax.tree.map(lambda *m: jnp.stack(m), *metrics))

    return stacked


def default_staged() -> bool:
    """Whether a run's chunk runs in stages (:class:`StagedChunk`) unless told: on an
    accelerator, where the walker's first chunk ended 7-15 s sooner from the build's start
    on one H200; on a CPU, whose chunks compile in seconds (the main job on two cores
    showed no clear gain in stages), it stays one program."""
    return jax.default_backend() != "cpu"


@functools.lru_cache(maxsize=4)
def build_programs(
    resolved: ResolvedConfig, devices: int | None = None, staged: bool | None = None
) -> Programs:
    """Env, trainer, the jitted init and chunk over seeds (on one device
    :func:`over_seeds`; over a mesh, ``jax.vmap``), and the evaluator.

    On one device a trainer with :class:`Stages` runs its chunk as their programs
    (:class:`StagedChunk`) when ``staged`` (``None``: :func:`default_staged`); over a mesh
    the chunk is one program.

    The evaluator is compiled on a background thread from :meth:`Programs.start_evaluator`
    on, which the run loop calls once the first chunk has compiled: its compile then
    overlaps the training chunks' run rather than the first chunk's tracing and compile
    (on one H200, alternating processes, that contention had cost the walker's first chunk
    3-9 s). Cached per config, so a resume or a second run in the same process reuses the
    compiled programs. Over more than one device (``devices``; ``None``:
    :func:`jaxenvs.run.placement.run_mesh`), init and chunk split the env batch over a mesh
    of them (:func:`jaxenvs.run.placement.mesh_programs`).

    On one device with the chunk as one program, where :func:`program_store_for` gives a
    store (the compile cache on, a task, trainer and configs of this package, not the C
    engine's callback path), init, chunk and evaluator are loaded traced from it, or
    traced and stored there; a program the store cannot hold is compiled as usual. Init
    is traced once either way, for the training state's structure.
    """
    env, trainer = build(resolved)
    mesh = run_mesh(
        resolved.agent.num_envs, env.physics, devices, figures_for(type(env)).c_envs_per_device
    )
    init_fn: Any  # jitted: ``eval_shape`` and ``lower`` below
    chunk_fn: Any
    if mesh.size > 1:  # laid out over the mesh, the evaluator too (jaxenvs.run.placement)
        trainer, init_fn, chunk_fn, compile_evaluate = mesh_programs(resolved, env, trainer, mesh)
        return Programs(env, trainer, init_fn, chunk_fn, BackgroundCompile(compile_evaluate))
    seeds = resolved.train.num_seeds
    if staged is None:
        staged = default_staged()
    staged = staged and trainer.stages is not None
    init_fn = jit_once(over_seeds(trainer.init, seeds))
    if staged:
        assert trainer.stages is not None
        chunk_fn = StagedChunk(trainer.stages, seeds)
    else:
        chunk_fn = jit(over_seeds(trainer.chunk, seeds))
    evaluator = jax.vmap(make_evaluator(env, trainer.act, resolved.train.eval_episodes), (0, None))
    keys = seed_keys(resolved.train.seed, seeds)
    key_shape = jax.eval_shape(lambda: eval_key(0))
    template = init_fn.eval_shape(keys)  # the training state's structure
    params_shape = jax.eval_shape(jax.vmap(trainer.policy_params), template)
    store = None if staged else program_store_for(resolved, env)
    if store is not None:  # traced once, then loaded (jaxenvs.run.program_store)
        stored = store(over_seeds(trainer.init, seeds), (keys,), "init", jit_once, (template,))
        init_fn = stored or init_fn
        stored = store(over_seeds(trainer.chunk, seeds), (template,), "chunk", jit, (template,))
        chunk_fn = stored or chunk_fn
    if not staged:
        chunk_fn = BackgroundChunk(chunk_fn)

    def compiled_evaluator() -> Any:
        args = (params_shape, key_shape)
        if store is not None:
            episode = jax.eval_shape(env.reset, jax.random.key(0))  # the trajectory's structure
            stored = store(evaluator, args, "eval", jit, (episode,))
            if stored is not None:
                return stored.lower(*args).compile()
        return jit(evaluator).lower(*args).compile()

    return Programs(env, trainer, init_fn, chunk_fn, BackgroundCompile(compiled_evaluator))


#: modules whose tasks, trainers and configs may have their programs stored: a stored
#: program's key covers the package's own files only (:mod:`jaxenvs.run.program_store`)
STORE_MODULES: tuple[str, ...] = ("jaxenvs.",)


def store_settings(resolved: ResolvedConfig, env: Env) -> dict[str, Any] | None:
    """What, besides the package's files and the arguments, a run's stored programs
    depend on: the resolved config (less the run settings that change no program) and the
    engine (the C engine's path, threads and derived fields are attributes of its native
    call). ``None`` where programs are not stored: for a task, trainer or config class
    not defined in this package (the key covers only the package's files), and for a C
    engine stepped through its Python callback, which an exported program cannot hold."""
    factory = registry.spec(resolved.env_id).factory
    owners = (
        type(env).__module__,
        getattr(factory, "__module__", ""),
        ALGORITHMS[resolved.algo].module,
        type(resolved.agent).__module__,
        type(resolved.env).__module__,
    )
    if not all(str(m).startswith(STORE_MODULES) for m in owners):
        return None
    engine = getattr(env.sim, "engine", None)
    if env.physics != "mjx" and getattr(engine, "path", None) != "native":
        return None
    settings = resolved.to_dict()
    settings["engine"] = {
        "physics": env.physics,
        "path": getattr(engine, "path", None),
        "threads": getattr(engine, "threads", None),
        "derived": getattr(env.sim, "derived", None),
    }
    # the run settings that change no program (a key without them is shared by more runs)
    unused = ("seed", "video", "eval_every")
    settings["train"] = {k: v for k, v in settings["train"].items() if k not in unused}
    return settings


def program_store_for(
    resolved: ResolvedConfig, env: Env
) -> Callable[..., program_store.Program | None] | None:
    """``store(fn, args, name, wrap, known)``, which loads ``fn``'s program traced by an
    earlier run or traces and stores it (:func:`jaxenvs.run.program_store.load_or_export`;
    ``None`` for a program that cannot be stored), or ``None`` while the compile cache is
    off and where :func:`store_settings` is ``None``."""
    cache = compile_cache.active()
    settings = store_settings(resolved, env)
    if cache is None or settings is None:
        return None

    def store(
        fn: Callable[..., Any],
        args: tuple[Any, ...],
        name: str,
        wrap: Callable[..., Any],
        known: tuple[Any, ...],
    ) -> program_store.Program | None:
        return program_store.load_or_export(
            fn,
            args,
            name=f"{resolved.algo}-{resolved.env_id}-{name}",
            config=settings,
            directory=cache / program_store.SUBDIR,
            jit=wrap,
            known=known,
        )

    return store


def over_seeds(fun: Callable[..., Any], num_seeds: int) -> Callable[..., Any]:
    """``fun`` over a leading seed axis of its arguments and results: ``jax.vmap(fun)``
    for several seeds; for one, ``fun`` itself between dropping that axis and restoring
    it. The single seed's program is then traced without batching its loops, whose
    batching rule traces each loop body again (the walker's chunk: 2.8 s of tracing
    rather than 4.8 s on two cores). It is the same computation, but XLA compiles it into
    another program, so a seed trained alone does not match that seed of a batch of seeds
    bit for bit."""
    if num_seeds > 1:
        return jax.vmap(fun)

    def one(*args: Any) -> Any:
        out = fun(*jax.tree.map(lambda x: x[0], args))
        return jax.tree.map(lambda x: x[None], out)

    return one
