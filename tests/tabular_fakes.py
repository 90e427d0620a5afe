"""Tiny physics-free discrete tasks for fast agent and runner tests (no MJX compile).

* ``Test-OneState-v0``: one observation (0), 2 actions, reward 1 per step; every
  episode lasts ``episode_length`` steps and ends terminated (``terminate=True``) or
  truncated. With episode_length 1 the fixed point of the Q-value is 1 when terminal
  transitions do not bootstrap and 1 / (1 - gamma) when truncated ones do.
* ``Test-Chain-v0``: position 0..length on a line; action 1 steps right, 0 steps left
  (floored at 0); reaching ``length`` pays 1 and terminates; truncation after
  ``episode_length`` steps. A random walk rarely gets there in time; going right always
  does.
"""

from __future__ import annotations

import contextlib
import dataclasses
from collections.abc import Callable, Iterator

import jax
import jax.numpy as jnp
import pytest
from flax import struct

from jaxenvs import registry
from jaxenvs.core import Env, NoExtras, TaskConfig


class FakeSim:
    """What a task needs of its sim when there is no physics: a control period, an engine
    to be stepped by (any engine steps nothing the same way) and the auto-reset's merge."""

    physics = "mjx"
    control_dt = 0.02

    def with_physics(self, physics: str, threads: int | None = None) -> FakeSim:
        return self

    def select_data(
        self, pick: Callable[[jax.Array, jax.Array], jax.Array], new: FakeData, old: FakeData
    ) -> FakeData:
        return jax.tree.map(pick, new, old)  # every field, as jaxenvs.physics.sim.Sim does


class FakeData(struct.PyTreeNode):
    qpos: jax.Array
    qvel: jax.Array


@dataclasses.dataclass(frozen=True)
class OneStateConfig(TaskConfig):
    episode_length: int = 1
    terminate: bool = False


class OneState(Env[OneStateConfig]):
    def __init__(self, config: OneStateConfig | None = None) -> None:
        super().__init__(config or OneStateConfig(), FakeSim())  # type: ignore[arg-type]

    observation_size = 1
    action_size = 2
    discrete = True
    default_params = None

    def _init(self, key, params):  # type: ignore[no-untyped-def]
        return FakeData(qpos=jnp.zeros(1), qvel=jnp.zeros(1)), NoExtras()

    def _act(self, key, data, extras, action, params):  # type: ignore[no-untyped-def]
        return data, extras

    def _observe(self, key, data, extras, params):  # type: ignore[no-untyped-def]
        return data.qpos

    def _reward(self, prev, data, action, extras, params):  # type: ignore[no-untyped-def]
        return jnp.ones((), jnp.float32), {}

    def _terminated(self, data, extras, params):  # type: ignore[no-untyped-def]
        return jnp.asarray(self.config.terminate)


@dataclasses.dataclass(frozen=True)
class ChainConfig(TaskConfig):
    episode_length: int = 12
    length: int = 6


class Chain(Env[ChainConfig]):
    def __init__(self, config: ChainConfig | None = None) -> None:
        super().__init__(config or ChainConfig(), FakeSim())  # type: ignore[arg-type]

    observation_size = 1
    action_size = 2
    discrete = True
    default_params = None

    def _init(self, key, params):  # type: ignore[no-untyped-def]
        return FakeData(qpos=jnp.zeros(1), qvel=jnp.zeros(1)), NoExtras()

    def _act(self, key, data, extras, action, params):  # type: ignore[no-untyped-def]
        step = jnp.where(action == 1, 1.0, -1.0)
        return data.replace(qpos=jnp.maximum(data.qpos + step, 0.0)), extras

    def _observe(self, key, data, extras, params):  # type: ignore[no-untyped-def]
        return data.qpos

    def _reward(self, prev, data, action, extras, params):  # type: ignore[no-untyped-def]
        return (data.qpos[0] >= self.config.length).astype(jnp.float32), {}

    def _terminated(self, data, extras, params):  # type: ignore[no-untyped-def]
        return data.qpos[0] >= self.config.length


FAKES = {
    "Test-OneState-v0": registry.EnvSpec("Test-OneState-v0", OneState, OneStateConfig()),
    "Test-Chain-v0": registry.EnvSpec("Test-Chain-v0", Chain, ChainConfig()),
}


@contextlib.contextmanager
def fake_envs() -> Iterator[None]:
    """Make the fake ids resolvable by the registry, then remove them again.

    They go straight into the id table (no Gymnasium registration), so tests that walk
    ``list_envs()`` elsewhere never see them.
    """
    with pytest.MonkeyPatch.context() as mp:
        for env_id, spec in FAKES.items():
            mp.setitem(registry._REGISTRY, env_id, spec)
        yield


def chain_run(chunks: int, num_seeds: int, **env: object) -> dict[str, object]:
    """A Q-learning run config of ``Test-Chain-v0`` (two envs, 30 steps a chunk):
    ``chunks`` chunks, ``num_seeds`` seeds, 3 evaluation episodes; ``env`` adds env
    settings. The chain pays at position 6."""
    return {
        "algo": "qlearning",
        "env": {"id": "Test-Chain-v0", "episode_length": 12, **env},
        "agent": {
            "alpha": 0.5,
            "gamma": 0.9,
            "number_splits": 7,
            "obs_low": [0.0],
            "obs_high": [7.0],
            "num_envs": 2,
            "chunk_steps": 30,
            "total_steps": 2 * 30 * chunks,
        },
        "train": {"num_seeds": num_seeds, "eval_episodes": 3, "video": False},
    }
