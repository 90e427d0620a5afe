"""Pure PPO math: generalised advantage estimation, the clipped losses and their sum.

Every function here is a pure function of arrays (no networks, no env), so each can be
checked against small hand-computed cases (``tests/agents/test_ppo.py``).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp


def gae(
    rewards: jax.Array,
    values: jax.Array,
    next_values: jax.Array,
    terminated: jax.Array,
    done: jax.Array,
    gamma: float,
    lam: float,
) -> tuple[jax.Array, jax.Array]:
    """Generalised advantage estimates over a time-major rollout.

    All inputs have shape ``(T, ...)``. ``next_values[t]`` is the value of the state the
    transition ``t`` really ended in (for a truncated episode, the value of
    ``info["final_obs"]``, not of the fresh reset observation). Termination cuts the
    bootstrap; the end of an episode (``done`` = terminated or truncated) cuts the
    lambda-trace, so a truncated step still bootstraps from its own next value::

        delta_t = r_t + gamma * (1 - terminated_t) * next_values_t - values_t
        A_t     = delta_t + gamma * lam * (1 - done_t) * A_{t+1},   A_T = 0

    Returns ``(advantages, returns)`` with ``returns = advantages + values``.
    """
    not_term = 1.0 - terminated.astype(rewards.dtype)
    not_done = 1.0 - done.astype(rewards.dtype)
    deltas = rewards + gamma * not_term * next_values - values

    def body(carry: jax.Array, x: tuple[jax.Array, jax.Array]) -> tuple[jax.Array, jax.Array]:
        delta, nd = x
        adv = delta + gamma * lam * nd * carry
        return adv, adv

    _, advantages = jax.lax.scan(body, jnp.zeros_like(deltas[0]), (deltas, not_done), reverse=True)
    return advantages, advantages + values


def policy_loss(
    log_prob: jax.Array, old_log_prob: jax.Array, advantages: jax.Array, clip_eps: float
) -> jax.Array:
    """Clipped surrogate objective, negated for minimisation (a scalar mean)."""
    ratio = jnp.exp(log_prob - old_log_prob)
    unclipped = ratio * advantages
    clipped = jnp.clip(ratio, 1.0 - clip_eps, 1.0 + clip_eps) * advantages
    return -jnp.mean(jnp.minimum(unclipped, clipped))


def value_loss(
    values: jax.Array, old_values: jax.Array, returns: jax.Array, clip_eps: float | None
) -> jax.Array:
    """``0.5 * mean((V - R)^2)``; with ``clip_eps``, the pessimistic max with the error of
    ``old_values + clip(V - old_values, -clip_eps, clip_eps)`` (PPO2-style)."""
    err = jnp.square(values - returns)
    if clip_eps is not None:
        clipped = old_values + jnp.clip(values - old_values, -clip_eps, clip_eps)
        err = jnp.maximum(err, jnp.square(clipped - returns))
    return 0.5 * jnp.mean(err)


def normalize_advantages(advantages: jax.Array, eps: float = 1e-8) -> jax.Array:
    """Zero mean, unit standard deviation (over all entries)."""
    return (advantages - advantages.mean()) / (advantages.std() + eps)


def approx_kl(log_prob: jax.Array, old_log_prob: jax.Array) -> jax.Array:
    """The low-variance estimator ``mean((r - 1) - log r)`` of KL(old || new)."""
    log_ratio = log_prob - old_log_prob
    return jnp.mean(jnp.expm1(log_ratio) - log_ratio)


def ppo_loss(
    log_prob: jax.Array,
    old_log_prob: jax.Array,
    advantages: jax.Array,
    values: jax.Array,
    old_values: jax.Array,
    returns: jax.Array,
    entropy: jax.Array,
    *,
    clip_eps: float,
    clip_value: bool,
    vf_coef: float,
    ent_coef: float,
    normalize_adv: bool,
) -> tuple[jax.Array, dict[str, jax.Array]]:
    """The PPO objective of one minibatch and its parts.

    All array inputs have one entry per sample: the new and the behaviour policy's log
    probabilities of the actions taken, the advantages, the new and the behaviour values,
    the returns (value targets) and the new policy's entropies. With ``normalize_adv``
    the advantages are normalised over the minibatch first; ``clip_value`` clips the value
    update with ``clip_eps`` as well (see :func:`value_loss`)::

        total = policy_loss + vf_coef * value_loss - ent_coef * mean(entropy)

    Returns ``(total, {"policy_loss", "value_loss", "entropy", "approx_kl"})``, where
    ``entropy`` is the mean entropy.
    """
    if normalize_adv:
        advantages = normalize_advantages(advantages)
    pi_loss = policy_loss(log_prob, old_log_prob, advantages, clip_eps)
    v_loss = value_loss(values, old_values, returns, clip_eps if clip_value else None)
    mean_entropy = entropy.mean()
    total = pi_loss + vf_coef * v_loss - ent_coef * mean_entropy
    aux = {
        "policy_loss": pi_loss,
        "value_loss": v_loss,
        "entropy": mean_entropy,
        "approx_kl": approx_kl(log_prob, old_log_prob),
    }
    return total, aux
