"""Random actions of an env's action space: for rollouts, benchmarks and tests alike."""

from __future__ import annotations

from typing import TYPE_CHECKING

import jax

if TYPE_CHECKING:
    from jaxenvs.core import Env


def random_actions(env: Env, key: jax.Array, batch: tuple[int, ...] = ()) -> jax.Array:
    """Uniform random actions of ``env``'s action space, with leading shape ``batch``.

    Discrete tasks: int32 in ``[0, action_size)``; continuous tasks: float32 uniform in
    ``[-1, 1]`` of shape ``(*batch, action_size)``.
    """
    if env.discrete:
        return jax.random.randint(key, batch, 0, env.action_size)
    return jax.random.uniform(key, (*batch, env.action_size), minval=-1.0, maxval=1.0)
