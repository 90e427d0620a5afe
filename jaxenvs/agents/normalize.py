"""Running mean and variance of a stream of batches: PPO's observation and return
normalisers (the exported policy folds the observation one in, :mod:`jaxenvs.deploy`)."""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp


class RunningStats(NamedTuple):
    """Mean and variance of a stream of batches (Chan et al.'s parallel merge)."""

    mean: jax.Array
    var: jax.Array
    n: jax.Array


def stats_init(shape: tuple[int, ...]) -> RunningStats:
    return RunningStats(
        jnp.zeros(shape, jnp.float32), jnp.ones(shape, jnp.float32), jnp.asarray(1e-4, jnp.float32)
    )  # strongly typed: a weak count would differ from a restored one and recompile


def stats_update(stats: RunningStats, batch: jax.Array) -> RunningStats:
    """Merge a batch (leading axis = samples) into the running statistics."""
    n = batch.shape[0]
    b_mean = batch.mean(axis=0)
    b_var = batch.var(axis=0)
    total = stats.n + n
    delta = b_mean - stats.mean
    mean = stats.mean + delta * n / total
    m2 = stats.var * stats.n + b_var * n + jnp.square(delta) * stats.n * n / total
    return RunningStats(mean, m2 / total, total)


def normalize(stats: RunningStats, x: jax.Array, clip: float) -> jax.Array:
    return jnp.clip((x - stats.mean) / jnp.sqrt(stats.var + 1e-8), -clip, clip)
