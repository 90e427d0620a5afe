"""Running mean and variance of a stream of batches: PPO's observation and return
normalisers (the exported policy folds the observation one in, :mod:`jaxenvs.deploy`).

Over several devices (:mod:`jaxenvs.agents.ppo.parallel`) each device merges its own
batches into an accumulator that starts empty (:func:`stats_empty`); the devices' shares
are then summed once (:func:`shifted_sums`, one ``psum``) and merged into the statistics
they all share (:func:`merge_sums`): the same statistics as one stream of every batch, up
to rounding.
"""

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


def stats_empty(shape: tuple[int, ...]) -> RunningStats:
    """Statistics of no sample (count 0): :func:`stats_update` of it and a batch gives
    the batch's own mean and variance."""
    zeros = jnp.zeros(shape, jnp.float32)
    return RunningStats(zeros, zeros, jnp.zeros((), jnp.float32))


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


#: an accumulator's count, and its samples' sums of ``x - center`` and ``(x - center)^2``
Sums = tuple[jax.Array, jax.Array, jax.Array]


def shifted_sums(acc: RunningStats, center: jax.Array) -> Sums:
    """``acc``'s samples as sums that add across devices: their count, and the sums of
    ``x - center`` and ``(x - center)^2`` (about ``center``, the statistics every device
    shares, so that the squares stay small and the variance keeps its precision)."""
    d = acc.mean - center
    return acc.n, acc.n * d, acc.n * (acc.var + jnp.square(d))


def merge_sums(stats: RunningStats, sums: Sums) -> RunningStats:
    """``stats`` merged with the samples whose :func:`shifted_sums` about ``stats.mean``
    (added over devices) are ``sums``; a count of 0 leaves ``stats`` as it is."""
    c, s1, s2 = sums
    safe = jnp.maximum(c, 1e-12)
    d = s1 / safe
    b_var = jnp.maximum(s2 / safe - jnp.square(d), 0.0)
    total = stats.n + c
    mean = stats.mean + d * c / total
    m2 = stats.var * stats.n + b_var * c + jnp.square(d) * stats.n * c / total
    return RunningStats(mean, m2 / total, total)


def normalize(stats: RunningStats, x: jax.Array, clip: float) -> jax.Array:
    return jnp.clip((x - stats.mean) / jnp.sqrt(stats.var + 1e-8), -clip, clip)
