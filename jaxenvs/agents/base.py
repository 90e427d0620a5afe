"""The interface every agent implements, so one runner trains, evaluates and renders all.

An algorithm module (``jaxenvs/agents/tabular.py``, ``jaxenvs/agents/ppo.py``) exposes a
frozen config dataclass and ``make_trainer(env, config) -> Trainer``. A :class:`Trainer`
is a bundle of pure, jittable functions:

* ``init(key) -> runner_state``: a pytree (a NamedTuple) holding everything training
  needs: network/Q-table params, optimiser state, env states, keys, counters.
* ``chunk(runner_state) -> (runner_state, metrics)``: advance training by
  ``steps_per_chunk`` env steps (a ``lax.scan`` inside); ``metrics`` is a dict of scalar
  arrays with at least the keys in :data:`CHUNK_METRICS`.
* ``policy_params(runner_state) -> pytree``: what the greedy policy needs.
* ``act(policy_params, obs, key) -> action``: the deterministic/greedy action for ONE
  observation (the key is for tie-breaking only); jittable and vmappable.
* ``stages`` (optional): the chunk cut into the programs it runs in order
  (:class:`Stages`), for a runner that compiles them apart (``chunk`` is
  :func:`chunk_of` them).

The full run is one compiled program: ``train(key)`` = ``init`` then a ``lax.scan`` of
``chunk`` (see :func:`make_train`); ``vmap`` over keys trains many seeds at once. The
command-line runner instead jits ``vmap(chunk)`` and loops over chunks in Python to show
progress, write ``progress.csv`` and checkpoint between chunks.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import jax

PyTree = Any

#: keys every chunk's metrics dict has (scalars per seed).
CHUNK_METRICS = (
    "env_steps",  # total env steps so far (int)
    "episodes",  # total finished episodes so far (int)
    "mean_return",  # mean return of episodes finished in this chunk (nan if none)
    "max_return",  # max return of episodes finished in this chunk (nan if none)
    "mean_length",  # mean length of episodes finished in this chunk (nan if none)
    "episodes_in_chunk",  # episodes finished in this chunk (int)
)


@dataclass(frozen=True)
class Stages:
    """A chunk as the steps it runs: ``count`` updates, each ``learn(*collect(state))``,
    then ``finish(state, metrics)`` with the updates' metrics stacked along a leading
    axis. Pure and jittable each; :func:`chunk_of` is the chunk they make."""

    collect: Callable[[PyTree], tuple[PyTree, PyTree]]  # state -> (state, batch)
    learn: Callable[[PyTree, PyTree], tuple[PyTree, dict[str, jax.Array]]]
    finish: Callable[[PyTree, dict[str, jax.Array]], dict[str, jax.Array]]
    count: int


def chunk_of(stages: Stages) -> Callable[[PyTree], tuple[PyTree, dict[str, jax.Array]]]:
    """The chunk ``stages`` make, one function: a ``lax.scan`` of the updates, then
    ``finish``."""

    def update(state: PyTree, _: None) -> tuple[PyTree, dict[str, jax.Array]]:
        return stages.learn(*stages.collect(state))

    def chunk(state: PyTree) -> tuple[PyTree, dict[str, jax.Array]]:
        state, metrics = jax.lax.scan(update, state, None, length=stages.count)
        return state, stages.finish(state, metrics)

    return chunk


@dataclass(frozen=True)
class Trainer:
    """Pure functions of one training setup (see the module docstring)."""

    init: Callable[[jax.Array], PyTree]
    chunk: Callable[[PyTree], tuple[PyTree, dict[str, jax.Array]]]
    policy_params: Callable[[PyTree], PyTree]
    act: Callable[[PyTree, jax.Array, jax.Array], jax.Array]
    steps_per_chunk: int
    num_chunks: int
    stages: Stages | None = None


def make_train(trainer: Trainer) -> Callable[[jax.Array], tuple[PyTree, dict[str, jax.Array]]]:
    """``train(key) -> (final runner_state, metrics stacked over chunks)``, one program."""

    def train(key: jax.Array) -> tuple[PyTree, dict[str, jax.Array]]:
        state = trainer.init(key)

        def body(s: PyTree, _: None) -> tuple[PyTree, dict[str, jax.Array]]:
            return trainer.chunk(s)

        return jax.lax.scan(body, state, None, length=trainer.num_chunks)

    return train
