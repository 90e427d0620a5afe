"""Does an exported policy act as the JAX policy it came from? On real rollouts.

:func:`jax_policy` is the greedy policy ``jaxenvs eval`` acts with (the trainer's ``act``
on the restored params of one seed); :func:`rollout_observations` collects the
observations that policy meets in its own env (auto-resetting envs, fresh random starts);
:func:`compare` sets the actions of an exported file against the JAX ones:

    policy = jax_policy(run_dir, seed)
    obs = rollout_observations(policy, 10_240)
    row = compare(policy.actions(obs), onnx_actions("policy.onnx", obs), policy.env.discrete)
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from jaxenvs.core.xla import jit


@dataclass(frozen=True)
class JaxPolicy:
    """One seed's greedy policy of a run: ``act(obs, key) -> action`` for ONE observation."""

    env: Any
    act: Callable[[jax.Array, jax.Array], jax.Array]

    def actions(self, obs: np.ndarray) -> np.ndarray:
        """The greedy actions of a batch ``(N, obs_size)``, as ``jaxenvs eval`` computes them."""
        keys = jax.random.split(jax.random.key(0), obs.shape[0])  # unused by the greedy policy
        return np.asarray(jit(jax.vmap(self.act))(jnp.asarray(obs), keys))


def jax_policy(run_dir: str | Path, seed: int, physics: str | None = None) -> JaxPolicy:
    """Seed ``seed`` of a run's greedy policy, its env stepped by ``physics`` (default: the
    run's engine)."""
    from jaxenvs.run import restore

    _, env, trainer, params = restore.restore_policy(run_dir, physics)
    params = jax.tree.map(lambda x: x[seed], params)
    return JaxPolicy(env, lambda obs, key: trainer.act(params, obs, key))


def rollout_observations(
    policy: JaxPolicy, num_obs: int, seed: int = 0, num_envs: int = 64
) -> np.ndarray:
    """``(num_obs, obs_size)`` float32 observations met by ``num_envs`` auto-resetting envs
    acting with ``policy`` (time-major: every env's first step, then the second, ...)."""
    from jaxenvs.core import BatchedEnv

    benv = BatchedEnv(policy.env, num_envs, devices=1)
    steps = math.ceil(num_obs / num_envs)

    def run(key: jax.Array) -> jax.Array:
        reset_key, act_key = jax.random.split(key)

        def body(state: Any, k: jax.Array) -> tuple[Any, jax.Array]:
            action = jax.vmap(policy.act)(state.obs, jax.random.split(k, num_envs))
            return benv.step(state, action), state.obs

        _, obs = jax.lax.scan(body, benv.reset(reset_key), jax.random.split(act_key, steps))
        return obs

    obs = np.asarray(jit(run)(jax.random.key(seed)), np.float32)
    return obs.reshape(-1, obs.shape[-1])[:num_obs]


def onnx_actions(path: str | Path, obs: np.ndarray) -> np.ndarray:
    """The actions of an exported ONNX file for ``obs``, through onnxruntime on the CPU."""
    import onnxruntime

    session = onnxruntime.InferenceSession(str(path), providers=["CPUExecutionProvider"])
    return np.asarray(session.run(["action"], {"obs": np.asarray(obs, np.float32)})[0])


def compare(
    reference: np.ndarray, actions: np.ndarray, discrete: bool, tol: float = 1e-5
) -> dict[str, Any]:
    """How far ``actions`` are from ``reference``, one row per observation:
    ``max_abs_diff`` over every entry, and ``mismatches``, the observations whose action
    differs (a different discrete choice, or an entry more than ``tol`` away)."""
    reference, actions = np.asarray(reference), np.asarray(actions)
    if reference.shape != actions.shape:
        raise ValueError(f"actions of shape {actions.shape}, expected {reference.shape}")
    delta = np.abs(reference.astype(np.float64) - actions.astype(np.float64))
    per_obs = delta.reshape(delta.shape[0], -1).max(axis=1)
    mismatches = int(np.sum(per_obs > (0 if discrete else tol)))
    return {
        "observations": int(reference.shape[0]),
        "max_abs_diff": float(per_obs.max()),
        "mismatches": mismatches,
    }


__all__ = ["JaxPolicy", "compare", "jax_policy", "onnx_actions", "rollout_observations"]
