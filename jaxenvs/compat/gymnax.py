"""gymnax adapter: every jaxenvs id as a gymnax ``Environment``, for gymnax-API training code
(PureJaxRL-style loops, rejax, Stoix).

    from jaxenvs.compat import gymnax as jgx

    env, env_params = jgx.make("CartPole-v0")            # as gymnax.make(...)
    obs, state = env.reset(key, env_params)
    obs, state, reward, done, info = env.step(key, state, action, env_params)

:class:`GymnaxEnv` subclasses gymnax's own ``Environment`` (gymnax's classic API, the one
``gymnax<1`` ships and rejax, PureJaxRL and Stoix consume) and takes ONE env: vmap ``reset``
and ``step`` over keys (and states, actions) to batch it, as with gymnax's envs.

* ``reset(key, params) -> (obs, state)``; ``state`` is the jaxenvs
  :class:`~jaxenvs.core.State` (it has gymnax's ``time``).
* ``step(key, state, action, params) -> (obs, state, reward, done, info)`` with the
  auto-reset inside, as gymnax's envs do: where the step ends the episode (``done`` =
  terminated or truncated) the returned ``obs`` and ``state`` are a fresh random start drawn
  from ``key`` (with the task's carry after the finished episode, as
  :class:`~jaxenvs.core.BatchedEnv` starts it); ``reward`` and ``done`` still describe the
  step that ended it, and ``info["final_observation"]`` keeps its last observation (to
  bootstrap a truncated episode). Every random draw of a step (action noise, pushes, the
  fresh start) comes from ``key``, none from the state.
* ``info`` (fixed keys, arrays): ``discount`` (0.0 where the step terminated, else 1.0),
  ``terminated``, ``truncated``, ``final_observation``, ``nan_actions``, ``diverged`` and the
  task's metrics (:attr:`~jaxenvs.core.Env.metric_keys`).
* Params are gymnax params, :class:`EnvParams`: ``max_steps_in_episode`` (the time limit;
  the task's ``episode_length`` only sets its default; a traced value, so it may differ
  per env) and
  ``task``, the task's own params pytree (masses, gains, target ranges, ...). Domain
  randomisation goes through them: :meth:`GymnaxEnv.sample_params` draws ``task`` from the
  task's randomisation ranges; vmap it over keys and pass the batch to a vmapped ``step``
  with ``in_axes=0`` for params.
* ``observation_space(params)`` / ``action_space(params)`` are gymnax spaces: a float32
  ``Box(-inf, inf, (observation_size,))``; ``Discrete(n)`` for the discrete tasks, else
  ``Box(-1, 1, (action_size,))``.

Keys may be typed (``jax.random.key``) or raw (``jax.random.PRNGKey``); states keep typed
keys either way.
"""

from __future__ import annotations

import functools
from typing import Any

import jax
import jax.numpy as jnp
from flax import struct

try:
    from gymnax.environments import environment, spaces
except ModuleNotFoundError as err:  # pragma: no cover - depends on the optional extra
    raise ModuleNotFoundError(
        "jaxenvs.compat.gymnax needs gymnax: pip install 'jaxenvs[gymnax]'", name=err.name
    ) from err

from jaxenvs import registry
from jaxenvs.core import Env, State

__all__ = ["EnvParams", "GymnaxEnv", "make"]

#: keyword arguments of :func:`jaxenvs.make` that build a batch; a gymnax env is one env
_BATCH_ARGS = ("num_envs", "randomize", "devices")


@struct.dataclass
class EnvParams(environment.EnvParams):
    """gymnax params of a jaxenvs task: the time limit and the task's own params."""

    max_steps_in_episode: int = 1000
    task: Any = None


def _typed(key: jax.Array) -> jax.Array:
    """``key`` as a typed PRNG key (a raw ``PRNGKey`` is wrapped with the default impl)."""
    if jax.dtypes.issubdtype(key.dtype, jax.dtypes.prng_key):
        return key
    return jax.random.wrap_key_data(key)


class GymnaxEnv(environment.Environment):  # type: ignore[misc]
    """A jaxenvs task behind gymnax's ``Environment`` interface (see the module docstring).

    Args:
      env: one jaxenvs env (``jaxenvs.make(id)`` without ``num_envs``).
      name: the name gymnax reports (default: the task's class name).
    """

    def __init__(self, env: Env, name: str | None = None) -> None:
        if not isinstance(env, Env):
            raise TypeError(
                f"GymnaxEnv wraps ONE jaxenvs Env (vmap it to batch), got {type(env).__name__}"
            )
        self.jax_env = env
        self._name = name or type(env).__name__

    def __deepcopy__(self, memo: dict[int, Any]) -> GymnaxEnv:
        """The env itself: it holds no mutable state (training code such as rejax
        deep-copies its config, env included), and jitted methods keyed on it stay warm."""
        return self

    # ----------------------------------------------------------------- description
    @property
    def default_params(self) -> EnvParams:
        return EnvParams(
            max_steps_in_episode=int(self.jax_env.episode_length),
            task=self.jax_env.default_params,
        )

    def sample_params(self, key: jax.Array, params: EnvParams | None = None) -> EnvParams:
        """``params`` (default: :attr:`default_params`) with ``task`` drawn from the task's
        randomisation ranges (``Env.sample_params``); vmap over keys for a batch."""
        params = self.default_params if params is None else params
        return params.replace(task=self.jax_env.sample_params(_typed(key)))

    @property
    def name(self) -> str:
        return self._name

    @property
    def num_actions(self) -> int:
        """The number of discrete actions, or the action vector's size."""
        return int(self.jax_env.action_size)

    def observation_space(self, params: EnvParams | None = None) -> spaces.Box:
        del params
        return spaces.Box(-jnp.inf, jnp.inf, (self.jax_env.observation_size,), jnp.float32)

    def action_space(self, params: EnvParams | None = None) -> spaces.Space:
        del params
        if self.jax_env.discrete:
            return spaces.Discrete(self.jax_env.action_size)
        return spaces.Box(-1.0, 1.0, (self.jax_env.action_size,), jnp.float32)

    # ----------------------------------------------------------------- dynamics
    def reset_env(self, key: jax.Array, params: EnvParams) -> tuple[jax.Array, State]:
        """A fresh random start drawn from ``key`` under ``params.task``."""
        state = self.jax_env.reset(_typed(key), params.task)
        return state.obs, state

    def step_env(
        self, key: jax.Array, state: State, action: Any, params: EnvParams
    ) -> tuple[jax.Array, State, jax.Array, jax.Array, dict[str, jax.Array]]:
        """One step without the auto-reset; its random draws come from ``key``."""
        nxt = self.jax_env.step(state.replace(key=_typed(key)), action, params.task)
        terminated = nxt.terminated
        truncated = jnp.logical_and(nxt.time >= params.max_steps_in_episode, ~terminated)
        info = {
            "discount": jnp.where(terminated, 0.0, 1.0).astype(jnp.float32),
            "terminated": terminated,
            "truncated": truncated,
            "final_observation": nxt.obs,
            "nan_actions": nxt.info["nan_actions"],
            "diverged": nxt.info["diverged"],
            **{k: nxt.info[k] for k in self.jax_env.metric_keys},
        }
        return nxt.obs, nxt, nxt.reward, jnp.logical_or(terminated, truncated), info

    @functools.partial(jax.jit, static_argnames=("self",))
    def step(
        self, key: jax.Array, state: State, action: Any, params: EnvParams | None = None
    ) -> tuple[jax.Array, State, jax.Array, jax.Array, dict[str, jax.Array]]:
        """One step, then a fresh start where it ended the episode (see the module
        docstring); ``params=None``: :attr:`default_params`."""
        params = self.default_params if params is None else params
        key_step, key_reset = jax.random.split(_typed(key))
        _, nxt, reward, done, info = self.step_env(key_step, state, action, params)

        def fresh(final: State) -> State:
            # a new episode from the env's carry after the finished one (a task's
            # curriculum level, counters), as the batched env's auto-reset starts it
            carry = self.jax_env.next_carry(final, params.task)
            return self.jax_env.reset_carried(key_reset, params.task, carry)

        # unbatched, the fresh start is computed only where the episode ended; under vmap
        # both branches run and the batched predicate selects, as gymnax's own step does
        nxt = jax.lax.cond(done, fresh, lambda old: old, nxt)
        return nxt.obs, nxt, reward, done, info

    @functools.partial(jax.jit, static_argnames=("self",))
    def reset(self, key: jax.Array, params: EnvParams | None = None) -> tuple[jax.Array, State]:
        """A fresh random start; ``params=None``: :attr:`default_params`."""
        return self.reset_env(key, self.default_params if params is None else params)


def make(env_id: str, **overrides: Any) -> tuple[GymnaxEnv, EnvParams]:
    """``(env, env_params)`` for the registered ``env_id``, as ``gymnax.make`` returns them.

    ``overrides`` are fields of the task's config (as :func:`jaxenvs.make`); ``physics``
    is resolved for one env (pass ``physics="mjx"`` or ``"c"`` to choose for the batch you
    will vmap). An unknown id or field raises naming the valid ones.
    """
    batch = [k for k in _BATCH_ARGS if k in overrides]
    if batch:
        raise TypeError(
            f"jaxenvs.compat.gymnax.make builds ONE env; {', '.join(batch)} belong to "
            "jaxenvs.make: vmap reset/step to batch, and draw params with "
            "env.sample_params for domain randomisation"
        )
    env = registry.make(env_id, **overrides)
    assert isinstance(env, Env)
    gx = GymnaxEnv(env, name=env_id)
    return gx, gx.default_params
