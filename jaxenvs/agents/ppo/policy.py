"""What PPO carries and what its policy sees: the runner state, the rollout's
transitions, the policy heads and the network's inputs."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp

from jaxenvs.agents.networks import (
    ActorCritic,
    categorical_entropy,
    categorical_log_prob,
    gaussian_entropy,
    gaussian_log_prob,
)
from jaxenvs.agents.normalize import RunningStats, normalize
from jaxenvs.agents.ppo.config import PPOConfig
from jaxenvs.core import Env, State

PyTree = Any


class RunnerState(NamedTuple):
    """Everything one seed's training carries between chunks."""

    params: PyTree
    opt_state: PyTree
    obs_stats: RunningStats
    ret_stats: RunningStats
    disc_return: jax.Array  # (num_envs,) running discounted return (reward normalisation)
    env_state: State
    key: jax.Array
    env_steps: jax.Array
    episodes: jax.Array
    updates: jax.Array
    #: running statistics of the critic's ``critic_info`` inputs (``None`` without them)
    critic_stats: RunningStats | None = None


class PolicyParams(NamedTuple):
    """What the greedy policy needs: network params and the observation statistics."""

    params: PyTree
    obs_stats: RunningStats


class Transition(NamedTuple):
    obs: jax.Array
    critic_extra: jax.Array  # (..., len(critic_info)) as the critic saw them
    action: jax.Array
    log_prob: jax.Array
    value: jax.Array
    next_value: jax.Array
    reward: jax.Array
    terminated: jax.Array
    done: jax.Array
    final_return: jax.Array
    final_length: jax.Array
    diverged: jax.Array


def _sample_categorical(out: Any, key: jax.Array) -> jax.Array:
    return jax.random.categorical(key, out).astype(jnp.int32)


def _mode_categorical(out: Any) -> jax.Array:
    return jnp.argmax(out, axis=-1).astype(jnp.int32)


def _sample_gaussian(out: Any, key: jax.Array) -> jax.Array:
    mean, log_std = out
    return mean + jnp.exp(log_std) * jax.random.normal(key, mean.shape)


def _mode_gaussian(out: Any) -> jax.Array:
    return jnp.clip(out[0], -1.0, 1.0)


class PolicyHead(NamedTuple):
    """The distribution functions of one kind of policy output."""

    sample: Callable[[Any, jax.Array], jax.Array]
    log_prob: Callable[[Any, jax.Array], jax.Array]
    entropy: Callable[[Any], jax.Array]
    mode: Callable[[Any], jax.Array]


CATEGORICAL = PolicyHead(
    _sample_categorical, categorical_log_prob, categorical_entropy, _mode_categorical
)
GAUSSIAN = PolicyHead(
    _sample_gaussian,
    lambda out, a: gaussian_log_prob(out[0], out[1], a),
    lambda out: gaussian_entropy(out[1]),
    _mode_gaussian,
)


def make_network(env: Env, config: PPOConfig) -> ActorCritic:
    return ActorCritic(
        action_size=env.action_size,
        discrete=env.discrete,
        actor_hidden=config.actor_hidden,
        critic_hidden=config.critic_hidden,
        log_std_init=config.log_std_init,
    )


def apply_net(
    net: ActorCritic, params: PyTree, obs: jax.Array, critic_extra: jax.Array | None = None
) -> tuple[Any, jax.Array]:
    """The network's ``(policy output, value)`` of ``obs`` (and the critic's own inputs;
    ``None`` or an empty last axis: none)."""
    if critic_extra is not None and critic_extra.shape[-1] == 0:
        critic_extra = None
    return net.apply(params, obs, critic_extra)  # type: ignore[return-value]


def critic_inputs(info: dict[str, jax.Array], keys: tuple[str, ...], zero: Any) -> jax.Array:
    """The ``keys`` entries of a batch's ``info`` as ``(num_envs, len(keys))`` float32,
    zero where ``zero`` (per env: a fresh start, or a terminal state whose value is never
    used; ``False``: none) and where not finite (a diverged step's metrics, which the
    env does not clean as it cleans the observation)."""
    if not keys:
        return jnp.zeros((info["episode_length"].shape[0], 0), jnp.float32)
    x = jnp.stack([info[k].astype(jnp.float32) for k in keys], axis=-1)
    return jnp.where(jnp.asarray(zero)[..., None] | ~jnp.isfinite(x), 0.0, x)


def observe_critic(stats: RunningStats | None, x: jax.Array, config: PPOConfig) -> jax.Array:
    """What the critic sees of its ``critic_info`` inputs ``x`` (as :func:`observe`)."""
    return x if stats is None or not config.normalize_obs else normalize(stats, x, config.obs_clip)


def observe(stats: RunningStats, obs: jax.Array, config: PPOConfig) -> jax.Array:
    """What the policy sees of ``obs``: normalised and clipped with ``stats`` when
    ``normalize_obs``, else ``obs`` itself."""
    return normalize(stats, obs, config.obs_clip) if config.normalize_obs else obs


def check_critic_info(env: Env, keys: tuple[str, ...]) -> None:
    """Raise ``ValueError`` naming the ``critic_info`` keys that are not among ``env``'s
    metrics."""
    known = tuple(env.metric_keys)
    unknown = [k for k in keys if k not in known]
    if unknown:
        raise ValueError(
            f"critic_info: {', '.join(unknown)} not among {type(env).__name__}'s metrics "
            f"({', '.join(known) or 'none'})"
        )
