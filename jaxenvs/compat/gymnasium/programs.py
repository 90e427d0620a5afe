"""The facade's jitted functions, built once per task config and kept in a bounded cache.

A vector env's step is one jitted program for every autoreset mode: ``SAME_STEP`` is the
batched env's own step (:class:`~jaxenvs.core.BatchedEnv` resets the envs that finish in
it); ``NEXT_STEP`` steps every env without a reset and then replaces the envs that
finished at the PREVIOUS step (their state still flags it) with fresh starts, ignoring
their actions; ``DISABLED`` only steps. A fresh start is drawn with the env's own key as
the batched env's auto-reset draws it, so an env's episodes under ``NEXT_STEP`` start
where they start under ``SAME_STEP``, one step later.
"""

from __future__ import annotations

import collections
import dataclasses
from collections.abc import Callable
from typing import Any

import jax
import jax.numpy as jnp
from gymnasium.vector import AutoresetMode
from jax.sharding import NamedSharding, PartitionSpec

from jaxenvs import registry
from jaxenvs.compat.gymnasium.words import Bufs, Words
from jaxenvs.core import BatchedEnv, Env, State
from jaxenvs.core.placement import ENV_AXIS
from jaxenvs.core.xla import jit

#: info keys every env reports besides its task metrics.
BASE_INFO_KEYS = ("nan_actions", "diverged")
#: task configs whose jitted functions are kept (least recently used dropped first); an
#: env holds its own functions, so dropping them only ends their sharing.
CACHE_SIZE = 16


@dataclasses.dataclass(frozen=True)
class Programs:
    """Jitted functions of one (task config, batch, autoreset mode), shared by the facade
    instances made with it. State travels as ``bufs`` in ``words`` form.

    ``reset(seed) -> bufs`` (a uint32 seed of the JAX key; a vector env's: one per env,
    env i started with ``jax.random.key(seed[i])``); ``step(bufs, action) -> bufs``, which
    donates its ``bufs`` (except a SAME_STEP vector env's); ``unpack(bufs) -> State``.
    Vector env only (``batched`` set): ``reset_masked(bufs, seeds, mask) -> bufs``
    (donates its ``bufs``) starts afresh the envs where ``mask`` holds, each with its seed.
    """

    env: Env
    words: Words
    reset: Callable[[Any], Bufs]
    step: Callable[[Bufs, Any], Bufs]
    unpack: Callable[[Bufs], State]
    batched: BatchedEnv | None = None
    reset_masked: Callable[[Bufs, Any, Any], Bufs] | None = None


def info_keys(env: Env) -> tuple[str, ...]:
    """The info keys the facade reports for ``env``."""
    return BASE_INFO_KEYS + tuple(env.metric_keys)


def _build_single(env: Env) -> Programs:
    seed0 = jax.ShapeDtypeStruct((), jnp.uint32)
    words = Words(jax.eval_shape(lambda s: env.reset(jax.random.key(s)), seed0), info_keys(env))

    def reset(seed: jax.Array) -> Bufs:
        return words.pack(env.reset(jax.random.key(seed)))

    def step(bufs: Bufs, action: jax.Array) -> Bufs:
        return words.pack(env.step(words.unpack(bufs), action))

    return Programs(
        env=env,
        words=words,
        reset=jit(reset),
        step=jit(step, donate_argnums=0),
        unpack=jit(words.unpack),
    )


def _restart(task: BatchedEnv, state: State, mask: jax.Array, keys: jax.Array) -> State:
    """``state`` with the envs where ``mask`` holds started afresh with their ``keys``, as
    the batched env's auto-reset starts them (:meth:`~jaxenvs.core.BatchedEnv.restart`:
    the whole State of a new episode, from each env's carry after the finished one)."""
    return task.restart(state, mask, keys)


def _placed(task: BatchedEnv, fn: Callable[..., State]) -> Callable[..., State]:
    """``fn(state, ...)`` with the state's env axis kept split over the batch's devices."""
    if task.mesh is None:
        return fn
    split = NamedSharding(task.mesh, PartitionSpec(ENV_AXIS))

    def place(tree: Any) -> Any:
        return jax.lax.with_sharding_constraint(tree, jax.tree.map(lambda _: split, tree))

    return lambda state, *args: place(fn(place(state), *args))


def _advance(task: BatchedEnv, mode: AutoresetMode) -> Callable[[State, jax.Array], State]:
    """One vector step under ``mode`` (see the module docstring)."""
    if mode is AutoresetMode.SAME_STEP:
        return task.step
    step = jax.vmap(task.env.step)
    if mode is AutoresetMode.DISABLED:
        return _placed(task, step)

    def next_step(state: State, action: jax.Array) -> State:
        return _restart(task, step(state, action), state.done, state.key)

    return _placed(task, next_step)


def _build_vector(
    env: Env, num_envs: int, randomize: bool, devices: int | None, mode: AutoresetMode
) -> Programs:
    task = BatchedEnv(env, num_envs, randomize=randomize, devices=devices)
    seed0 = jax.ShapeDtypeStruct((), jnp.uint32)
    example = jax.eval_shape(lambda s: task.reset(jax.random.key(s)), seed0)
    same_step = mode is AutoresetMode.SAME_STEP
    words = Words(example, info_keys(env), (num_envs,), final_obs=same_step)
    advance = _advance(task, mode)
    restart = _placed(task, lambda state, mask, keys: _restart(task, state, mask, keys))
    start = _placed(task, lambda keys: task.fresh_starts(keys))
    keys_of = jax.vmap(jax.random.key)

    def reset(seeds: jax.Array) -> Bufs:
        return words.pack(start(keys_of(seeds)))

    def step(bufs: Bufs, action: jax.Array) -> Bufs:
        return words.pack(advance(words.unpack(bufs), action))

    def reset_masked(bufs: Bufs, seeds: jax.Array, mask: jax.Array) -> Bufs:
        return words.pack(restart(words.unpack(bufs), mask, keys_of(seeds)))

    # the batched env's own auto-reset (SAME_STEP) ran ~5% slower with its state donated
    # (Reacher, 256 envs, 2 cores); the other modes' steps gain or lose nothing measurable
    donate = () if same_step else 0
    return Programs(
        env=env,
        words=words,
        reset=jit(reset),
        step=jit(step, donate_argnums=donate),
        unpack=jit(words.unpack),
        batched=task,
        reset_masked=jit(reset_masked, donate_argnums=0),
    )


def _build(
    env_id: str,
    overrides: dict[str, Any],
    num_envs: int | None,
    randomize: bool,
    devices: int | None,
    mode: AutoresetMode,
) -> Programs:
    env = registry.make(env_id, **overrides)
    assert isinstance(env, Env)
    if num_envs is None:
        return _build_single(env)
    return _build_vector(env, num_envs, randomize, devices, mode)


_CACHE: collections.OrderedDict[Any, Programs] = collections.OrderedDict()


def compiled(
    env_id: str,
    overrides: dict[str, Any] | None = None,
    num_envs: int | None = None,
    randomize: bool = False,
    devices: int | None = None,
    mode: AutoresetMode = AutoresetMode.NEXT_STEP,
) -> Programs:
    """The jitted functions for ``env_id`` with ``overrides`` (one env where ``num_envs``
    is None), shared through a cache of the :data:`CACHE_SIZE` most recently used."""
    overrides = dict(overrides or {})
    config = registry.make_config(env_id, overrides, source=f"jaxenvs/{env_id} kwargs")
    mode = mode if num_envs is not None else AutoresetMode.NEXT_STEP
    try:
        key: Any = (registry.spec(env_id).factory, config, num_envs, randomize, devices, mode)
        hash(key)
    except TypeError:  # a config with unhashable fields: no sharing
        return _build(env_id, overrides, num_envs, randomize, devices, mode)
    if key in _CACHE:
        _CACHE.move_to_end(key)
        return _CACHE[key]
    built = _build(env_id, overrides, num_envs, randomize, devices, mode)
    _CACHE[key] = built
    while len(_CACHE) > CACHE_SIZE:
        _CACHE.popitem(last=False)
    return built
