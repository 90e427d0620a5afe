"""PPO's update: the optimiser, the minibatch shuffle and one epoch of gradient steps."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import jax
import optax

from jaxenvs.agents import losses
from jaxenvs.agents.networks import ActorCritic
from jaxenvs.agents.ppo.config import PPOConfig
from jaxenvs.agents.ppo.devices import ONE_DEVICE, Devices
from jaxenvs.agents.ppo.policy import PolicyHead, Transition, apply_net

PyTree = Any


def make_optimizer(config: PPOConfig) -> optax.GradientTransformation:
    """Adam (eps 1e-5) after global-norm gradient clipping; with ``anneal_lr`` its step
    size falls linearly to zero over every gradient step of the run."""
    c = config
    total_grad_steps = c.num_chunks * c.updates_per_chunk * c.update_epochs * c.num_minibatches
    lr: float | optax.Schedule = (
        optax.linear_schedule(c.learning_rate, 0.0, total_grad_steps)
        if c.anneal_lr
        else c.learning_rate
    )
    return optax.chain(optax.clip_by_global_norm(c.max_grad_norm), optax.adam(lr, eps=1e-5))


def shuffle_minibatches(key: jax.Array, data: PyTree, num_minibatches: int) -> PyTree:
    """One epoch's minibatches of a time-major rollout.

    Every leaf of ``data`` has shape ``(T, N, ...)``. Its ``T * N`` samples are flattened,
    shuffled by ONE permutation drawn from ``key`` (the same for every leaf, so a sample's
    fields stay together) and cut into ``num_minibatches`` equal minibatches: every leaf
    becomes ``(num_minibatches, T * N // num_minibatches, ...)``, and each sample appears
    exactly once. ``num_minibatches`` must divide ``T * N``.
    """
    first = jax.tree.leaves(data)[0]
    n = first.shape[0] * first.shape[1]

    perm = jax.random.permutation(key, n)

    def split(x: jax.Array) -> jax.Array:
        x = x.reshape((n, *x.shape[2:]))[perm]
        return x.reshape((num_minibatches, n // num_minibatches, *x.shape[1:]))

    return jax.tree.map(split, data)


#: an epoch's carry: network params, optimiser state, and the rollout
#: ``(transitions, advantages, returns)`` it passes over
EpochCarry = tuple[PyTree, PyTree, tuple[Transition, jax.Array, jax.Array]]


def make_epoch(
    net: ActorCritic,
    head: PolicyHead,
    tx: optax.GradientTransformation,
    config: PPOConfig,
    devices: Devices = ONE_DEVICE,
) -> Callable[[EpochCarry, jax.Array], tuple[EpochCarry, dict[str, jax.Array]]]:
    """``epoch(carry, key) -> (carry, stats)``: one pass over a rollout in
    :func:`shuffle_minibatches` order, one gradient step of :func:`losses.ppo_loss` per
    minibatch; ``stats`` holds each step's loss figures.

    On several ``devices`` each passes over its own rollout with its own key, and the
    devices meet once per gradient step: one ``pmean`` of the gradients and the loss
    figures, after which every device takes the same optimiser step.
    """
    c = config

    def loss_fn(
        params: PyTree, batch: Transition, adv: jax.Array, ret: jax.Array
    ) -> tuple[jax.Array, dict[str, jax.Array]]:
        out, value = apply_net(net, params, batch.obs, batch.critic_extra)
        logp = head.log_prob(out, batch.action)
        return losses.ppo_loss(
            logp,
            batch.log_prob,
            adv,
            value,
            batch.value,
            ret,
            head.entropy(out),
            clip_eps=c.clip_eps,
            clip_value=c.clip_value,
            vf_coef=c.vf_coef,
            ent_coef=c.ent_coef,
            normalize_adv=c.normalize_advantages,
        )

    grad_fn = jax.value_and_grad(loss_fn, has_aux=True)

    def sgd_step(
        carry: tuple[PyTree, PyTree], mb: tuple[Transition, jax.Array, jax.Array]
    ) -> tuple[tuple[PyTree, PyTree], dict[str, jax.Array]]:
        params, opt_state = carry
        batch, adv, ret = mb
        (loss, aux), grads = devices.mean(grad_fn(params, batch, adv, ret))
        updates, opt_state = tx.update(grads, opt_state, params)
        params = optax.apply_updates(params, updates)
        return (params, opt_state), {"loss": loss, **aux}

    def epoch(carry: EpochCarry, key: jax.Array) -> tuple[EpochCarry, dict[str, jax.Array]]:
        params, opt_state, data = carry
        minibatches = shuffle_minibatches(key, data, c.num_minibatches)
        (params, opt_state), stats = jax.lax.scan(sgd_step, (params, opt_state), minibatches)
        return (params, opt_state, data), stats

    return epoch
