"""Greedy-policy evaluation as one pure program, shared by training and restored runs.

:func:`make_evaluator` is what the end-of-run (and ``eval_every``) evaluation of
:func:`jaxenvs.run.runner.train` and :func:`jaxenvs.run.restore.evaluate_run` run;
:func:`eval_key` the key of the final evaluation; :func:`evaluator_jit` how a run compiles it.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import jax
import jax.numpy as jnp

from jaxenvs.core import Env
from jaxenvs.core.xla import jit, jit_once

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


def evaluator_jit(eval_every: int, physics: str) -> Callable[..., Any]:
    """How a run's evaluator is compiled: :func:`~jaxenvs.core.xla.jit_once` when the run
    evaluates only at its end (``eval_every`` 0) and its env steps in MuJoCo's C engine
    (``physics`` ``"c"``), :func:`~jaxenvs.core.xla.jit` otherwise. On a CPU the end-only
    evaluator compiles while the chunks run, sharing the machine with them; around the C
    engine (a native call) XLA compiles only the policy and the bookkeeping, and at -O0
    its compile took 0.2-0.6 s rather than 1.2-1.8 s on two cores (CartPole's, Reacher's
    and the walker's) and its one run 0.01-0.2 s longer. MJX's physics at -O0 runs
    slower by more than the compile saves (the walker's evaluation: 7.6 s of compile
    saved, 19 s of run lost)."""
    return jit_once if eval_every == 0 and physics == "c" else jit


def eval_key(seed: int) -> jax.Array:
    """The key of the final evaluation: independent of every training key."""
    return jax.random.fold_in(jax.random.key(seed), 2**31 - 1)
