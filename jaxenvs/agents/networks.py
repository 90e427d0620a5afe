"""Actor-critic MLPs and the action distributions PPO samples from.

Two separate tanh MLPs (actor and critic) with orthogonal initialisation: hidden layers
with gain sqrt(2), the policy output with gain 0.01 (near-uniform / near-zero-mean first
policy) and the value output with gain 1; biases start at zero.

* Discrete tasks: a categorical head (one logit per action).
* Continuous tasks: a Gaussian head whose mean comes from the actor MLP and whose log
  standard deviation is a learned, state-independent vector.

**Action bounds.** Gaussian samples are *clipped* to the action space [-1, 1] when they are
sent to the env (the env clips too), and the log-probability is that of the unclipped
sample, which is what the trajectory stores. We chose clipping over tanh-squashing: the
log-probabilities and entropy stay exact and closed-form (no change-of-variables term), and
the deterministic policy is ``clip(mean, -1, 1)``.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import flax.linen as nn
import jax
import jax.numpy as jnp


def _orthogonal(gain: float) -> nn.initializers.Initializer:
    """Flax's orthogonal initialiser, one matrix at a time even under ``vmap``.

    Its QR factorisation is a LAPACK call; ``vmap`` over seeds (the runner's ``init``,
    ``make_train``) makes it a batched one, which jaxlib splits over XLA's CPU thread pool
    and waits for on a worker of that same pool. With two such calls in flight (the actor's
    and the critic's layers) on a 2-core CPU both workers wait and the program never
    finishes (the deadlock of benchmarks/NOTES.md, here in ``lapack_sgeqrf_ffi``).
    ``sequential_vmap`` turns the batch into a loop of single QRs: the same numbers.
    """
    base = nn.initializers.orthogonal(gain)

    def init(key: jax.Array, shape: tuple[int, ...], dtype: jnp.dtype = jnp.float32) -> jax.Array:
        return jax.custom_batching.sequential_vmap(lambda k: base(k, shape, dtype))(key)

    return init


def _dense(features: int, gain: float) -> nn.Dense:
    return nn.Dense(
        features,
        kernel_init=_orthogonal(gain),
        bias_init=nn.initializers.zeros,
    )


class MLP(nn.Module):
    """tanh MLP: ``hidden`` layers of the given widths, then a linear output layer."""

    hidden: Sequence[int]
    out: int
    out_gain: float

    @nn.compact
    def __call__(self, x: jax.Array) -> jax.Array:
        for width in self.hidden:
            x = jnp.tanh(_dense(width, math.sqrt(2.0))(x))
        return _dense(self.out, self.out_gain)(x)


class ActorCritic(nn.Module):
    """``apply(params, obs, critic_extra=None) -> (policy_out, value)``.

    The critic sees ``obs`` followed by ``critic_extra`` (``(..., k)``: inputs only the
    critic has, e.g. privileged state in an asymmetric actor-critic); the actor sees
    ``obs`` alone. A network initialised with ``critic_extra`` must be applied with one
    of the same size (``policy`` needs none).

    ``policy_out`` is the logits ``(..., action_size)`` for a discrete task, else the pair
    ``(mean, log_std)`` each ``(..., action_size)``. ``value`` has shape ``(...)``.
    """

    action_size: int
    discrete: bool
    actor_hidden: Sequence[int] = (64, 64)
    critic_hidden: Sequence[int] = (64, 64)
    log_std_init: float = 0.0

    def setup(self) -> None:
        self.critic = MLP(self.critic_hidden, 1, 1.0)
        self.actor = MLP(self.actor_hidden, self.action_size, 0.01)
        if not self.discrete:
            self.log_std = self.param(
                "log_std", nn.initializers.constant(self.log_std_init), (self.action_size,)
            )

    def policy(self, obs: jax.Array) -> jax.Array | tuple[jax.Array, jax.Array]:
        """The policy output of ``obs`` alone (the critic is not evaluated)."""
        out = self.actor(obs)
        if self.discrete:
            return out
        return out, jnp.broadcast_to(self.log_std, out.shape)

    def __call__(
        self, obs: jax.Array, critic_extra: jax.Array | None = None
    ) -> tuple[jax.Array | tuple[jax.Array, jax.Array], jax.Array]:
        critic_in = obs if critic_extra is None else jnp.concatenate([obs, critic_extra], -1)
        value = self.critic(critic_in)[..., 0]
        return self.policy(obs), value


# ----------------------------------------------------------------------- distributions
def categorical_log_prob(logits: jax.Array, action: jax.Array) -> jax.Array:
    """log pi(action) for integer actions of shape ``logits.shape[:-1]``."""
    logp = jax.nn.log_softmax(logits)
    return jnp.take_along_axis(logp, action[..., None].astype(jnp.int32), axis=-1)[..., 0]


def categorical_entropy(logits: jax.Array) -> jax.Array:
    logp = jax.nn.log_softmax(logits)
    return -jnp.sum(jnp.exp(logp) * logp, axis=-1)


def gaussian_log_prob(mean: jax.Array, log_std: jax.Array, action: jax.Array) -> jax.Array:
    """log density of a diagonal Gaussian, summed over the last axis."""
    z = (action - mean) * jnp.exp(-log_std)
    return jnp.sum(-0.5 * z**2 - log_std - 0.5 * math.log(2.0 * math.pi), axis=-1)


def gaussian_entropy(log_std: jax.Array) -> jax.Array:
    return jnp.sum(log_std + 0.5 * math.log(2.0 * math.pi * math.e), axis=-1)
