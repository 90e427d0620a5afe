"""Greedy-policy evaluation as one pure program, shared by training and restored runs.

:func:`make_evaluator` is what the end-of-run (and ``eval_every``) evaluation of
:func:`jaxenvs.run.runner.train` and :func:`jaxenvs.run.restore.evaluate_run` run;
:func:`eval_key` the key of the final evaluation.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import jax
import jax.numpy as jnp

from jaxenvs.core import Env

PyTree = Any


def make_evaluator(
    env: Env, act: Callable[[PyTree, jax.Array, jax.Array], jax.Array], episodes: int
) -> Callable[[PyTree, jax.Array], tuple[jax.Array, Any, jax.Array]]:
    """``evaluate(params, key) -> (returns (episodes,), trajectory, length)``.

    Greedy episodes from fresh random starts, each until it terminates or truncates (no
    auto-reset). ``trajectory`` is the first episode's States stacked over time (the
    reset state first, ``episode_length + 1`` entries) and ``length`` its length, so
    a video needs no second compile.
    """

    def evaluate(params: PyTree, key: jax.Array) -> tuple[jax.Array, Any, jax.Array]:
        reset_key, act_key = jax.random.split(key)
        first = jax.vmap(env.reset)(jax.random.split(reset_key, episodes))

        def body(carry: tuple[Any, ...], k: jax.Array) -> tuple[tuple[Any, ...], Any]:
            state, done, ret, length = carry
            keys = jax.random.split(k, episodes)
            action = jax.vmap(act, in_axes=(None, 0, 0))(params, state.obs, keys)
            nxt = jax.vmap(env.step)(state, action)
            ret = ret + jnp.where(done, 0.0, nxt.reward)
            length = length + (~done).astype(jnp.int32)
            return (nxt, done | nxt.done, ret, length), jax.tree.map(lambda x: x[0], nxt)

        carry = (
            first,
            jnp.zeros(episodes, bool),
            jnp.zeros(episodes, jnp.float32),
            jnp.zeros(episodes, jnp.int32),
        )
        keys = jax.random.split(act_key, env.episode_length)
        (_, _, ret, length), traj = jax.lax.scan(body, carry, keys)
        head = jax.tree.map(lambda x: x[0], first)
        traj = jax.tree.map(lambda a, b: jnp.concatenate([a[None], b]), head, traj)
        traj = traj.replace(key=jax.random.key_data(traj.key))  # host-convertible
        return ret, traj, length[0]

    return evaluate


def eval_key(seed: int) -> jax.Array:
    """The key of the final evaluation: independent of every training key."""
    return jax.random.fold_in(jax.random.key(seed), 2**31 - 1)
