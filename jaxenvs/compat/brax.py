"""Brax adapter: train a jaxenvs task with Brax's training stack.

    from brax.training.agents.ppo import train as ppo
    from jaxenvs.compat.brax import BraxEnv

    env = BraxEnv(jaxenvs.make("CartpoleBalance-v0"))
    make_policy, params, metrics = ppo.train(
        environment=env, episode_length=env.episode_length, num_timesteps=1_000_000, ...)

:class:`BraxEnv` implements ``brax.envs.base.Env`` for ONE env (Brax vmaps it itself):

* ``reset(rng) -> State`` and ``step(state, action) -> State``, where Brax's ``State`` has
  ``pipeline_state`` = the whole jaxenvs :class:`~jaxenvs.core.State` (physics, task
  extras such as targets, episode counters and the env's key), ``obs``, ``reward``,
  ``done``, ``metrics`` (the task's metric keys) and ``info``.
* ``observation_size``, ``action_size``, ``backend`` (``"mjx"``), plus ``episode_length``
  and ``dt`` for convenience.

**Termination and truncation.** ``done`` is the task's *termination* only (a fall, a
divergence), as a float. The time limit is Brax's: ``train(..., episode_length=...)``
wraps the env in ``EpisodeWrapper``, which ends an episode after that many steps and sets
``info["truncation"] = 1`` on such a step, the flag Brax's PPO reads to bootstrap the value
instead of treating the end as terminal. Pass ``episode_length=env.episode_length`` to keep
the task's own limit. Without Brax's wrappers (``wrap_env=False``), ``info["truncation"]``
carries the task's own time-limit flag (``state.truncated``) and ``done`` stays
termination-only: end episodes where ``done or info["truncation"]``. ``info["time_out"]``
holds the same task flag for ``train(..., bootstrap_on_timeout=True)``.

**Resets.** Brax's ``AutoResetWrapper`` returns a finished env to the state that env
started from (its first reset), not to a fresh random one. Because ``pipeline_state`` is the
whole jaxenvs state, that reset is consistent (targets, counters and key go back together
with the physics); jaxenvs' own :class:`~jaxenvs.core.BatchedEnv` draws fresh starts
instead.

**JAX versions.** Brax 0.14 still calls ``jax.device_put_replicated`` and
``jax.device_put_sharded``, which JAX 0.10 removed. Importing this module restores the two
names on such JAX versions as the drop-in replacements of JAX's pmap migration guide
(:func:`jax.device_put` of the stacked value with a sharding over the devices), and does
nothing where JAX still has them.

Continuous-action tasks only: Brax's agents emit actions in [-1, 1], the range jaxenvs
tasks take. Params: ``BraxEnv(env, params=...)`` fixes the physical params used (default:
``env.default_params``).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

try:
    from brax.envs.base import Env as _BraxEnvBase
    from brax.envs.base import State as BraxState
except ModuleNotFoundError as err:  # pragma: no cover - depends on the optional extra
    raise ModuleNotFoundError(
        "jaxenvs.compat.brax needs Brax: pip install 'jaxenvs[brax]'", name=err.name
    ) from err

from jaxenvs.core import BatchedEnv, Env, State

__all__ = ["BraxEnv", "BraxState"]


def _stacked_on(devices: Sequence[jax.Device], stacked: Any) -> Any:
    mesh = jax.sharding.Mesh(np.array(list(devices)), ("d",))
    sharding = jax.sharding.NamedSharding(mesh, jax.sharding.PartitionSpec("d"))
    return jax.device_put(stacked, sharding)


def _device_put_replicated(x: Any, devices: Sequence[jax.Device]) -> Any:
    """``x`` copied along a new leading axis, one slice per device."""
    stacked = jax.tree.map(lambda a: jnp.stack([jnp.asarray(a)] * len(devices)), x)
    return _stacked_on(devices, stacked)


def _device_put_sharded(shards: Sequence[Any], devices: Sequence[jax.Device]) -> Any:
    """The pytrees in ``shards`` stacked along a new leading axis, slice i on device i."""
    stacked = jax.tree.map(lambda *a: jnp.stack([jnp.asarray(v) for v in a]), *shards)
    return _stacked_on(devices, stacked)


def _restore_removed_jax_helpers() -> None:
    for name, fn in (
        ("device_put_replicated", _device_put_replicated),
        ("device_put_sharded", _device_put_sharded),
    ):
        try:
            getattr(jax, name)
        except AttributeError:
            setattr(jax, name, fn)


_restore_removed_jax_helpers()


class BraxEnv(_BraxEnvBase):
    """A jaxenvs task behind Brax's ``Env`` interface (see the module docstring)."""

    def __init__(self, env: Env | BatchedEnv, params: Any = None) -> None:
        if isinstance(env, BatchedEnv):
            raise TypeError(
                "BraxEnv wraps ONE env (Brax batches it itself): pass jaxenvs.make(id) "
                "without num_envs"
            )
        if not isinstance(env, Env):
            raise TypeError(f"BraxEnv needs a jaxenvs Env, got {type(env).__name__}")
        if env.discrete:
            raise ValueError(
                f"{type(env).__name__} has discrete actions ({env.action_space}); Brax's "
                "agents need a continuous-action task"
            )
        self.env = env
        self.params = env.default_params if params is None else params

    # ----------------------------------------------------------------- description
    @property
    def observation_size(self) -> int:
        return int(self.env.observation_size)

    @property
    def action_size(self) -> int:
        return int(self.env.action_size)

    @property
    def backend(self) -> str:
        return "mjx"

    @property
    def episode_length(self) -> int:
        """The task's own time limit; pass it to Brax's ``train(episode_length=...)``."""
        return int(self.env.episode_length)

    @property
    def dt(self) -> float:
        """Seconds of simulated time per step."""
        return float(self.env.control_dt)

    @property
    def unwrapped(self) -> BraxEnv:
        return self

    # ----------------------------------------------------------------- dynamics
    def _to_brax(self, state: State) -> BraxState:
        metrics = {k: state.info[k] for k in self.env.metric_keys}
        truncated = state.truncated.astype(jnp.float32)
        info = {"truncation": truncated, "time_out": truncated}
        return BraxState(
            pipeline_state=state,
            obs=state.obs,
            reward=state.reward,
            done=state.terminated.astype(jnp.float32),
            metrics=metrics,
            info=info,
        )

    def reset(self, rng: jax.Array) -> BraxState:
        """Start an episode; ``rng`` is a raw ``PRNGKey`` or a typed key."""
        return self._to_brax(self.env.reset(rng, self.params))

    def step(self, state: BraxState, action: jax.Array) -> BraxState:
        """Advance one control step, keeping the entries Brax's wrappers added to
        ``state.info`` and ``state.metrics``."""
        nxt = self.env.step(state.pipeline_state, jnp.asarray(action, jnp.float32), self.params)
        out = self._to_brax(nxt)
        return out.replace(
            info={**state.info, **out.info}, metrics={**state.metrics, **out.metrics}
        )
