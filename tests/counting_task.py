"""A task that keeps a carry: CartPole-v0 with a per-env count of finished episodes (the
example of docs/custom_task.md, "A carry across episodes")."""

from __future__ import annotations

import jax
import jax.numpy as jnp

from jaxenvs.core import State
from jaxenvs.tasks.cartpole import CartPole, CartPoleConfig


class CountingCartPole(CartPole):
    """CartPole-v0 whose carry counts each env's finished episodes; the count also starts
    the cart that many millimetres to the right (so a start reads its carry)."""

    def _carry_init(self, key: jax.Array, params: object) -> jax.Array:
        del key, params
        return jnp.zeros((), jnp.int32)

    def _carry_update(self, carry: jax.Array, final: State, params: object) -> jax.Array:
        del final, params
        return carry + 1

    def _start(self, key: jax.Array, params: object, carry: jax.Array):  # type: ignore[no-untyped-def]
        data, extras = self._init(key, params)
        return data.replace(qpos=data.qpos.at[0].add(1e-3 * carry)), extras


def make(episode_length: int = 5, **overrides: object) -> CountingCartPole:
    config = CartPoleConfig(episode_length=episode_length, **overrides)  # type: ignore[arg-type]
    config.validate()
    return CountingCartPole(config)
