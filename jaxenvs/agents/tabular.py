"""Tabular Q-learning and SARSA over a uniformly discretised observation, fully on device.

The agent (the course's ``qlearn.py`` / ``sarsa.py``, vectorised):

* **Discretiser.** Each observation dimension ``i`` is cut into ``number_splits[i]`` equal
  bins between ``obs_low[i]`` and ``obs_high[i]``; values outside the bounds fall in the
  edge bins. The per-dimension bins are combined row-major into one state index.
* **Q-table.** A float32 JAX array ``(num_states, num_actions)``, zero at the start.
* **Behaviour.** Epsilon-greedy; the greedy action breaks ties uniformly at random.
* **Epsilon schedule.** Every env keeps its own finished-episode counter ``e``; its
  epsilon is ``max(epsilon_min, epsilon * epsilon_discount ** e)``, i.e. epsilon is
  multiplied by ``epsilon_discount`` once per episode of that env, down to the floor.
* **Targets.** Q-learning: ``r + gamma * max_b Q(s', b)``; SARSA: ``r + gamma * Q(s', a')``
  with ``a'`` the action the agent actually takes next. ``s'`` is ``info["final_obs"]``
  (the state the transition really ended in). Terminal transitions do not bootstrap
  (target ``r``); truncated ones do. On truncation no action is taken in ``s'`` (the env
  auto-resets), so SARSA bootstraps from an epsilon-greedy draw at ``s'``.
* **N envs, one table.** All envs step together and update one shared table once per
  step. When several envs hit the same ``(s, a)`` entry in the same step, the entry moves
  by ``alpha`` times the MEAN of their TD errors (a segment sum of the errors divided by
  the hit count): with one env this is exactly the textbook update, and the result does
  not depend on the order of the envs.
* **K seeds** are a ``vmap`` of the whole training over keys (the runner does this).

``make_trainer(env, config)`` returns a :class:`jaxenvs.agents.base.Trainer`. Only
discrete-action tasks are supported; a continuous one raises a clear error.
"""

from __future__ import annotations

import dataclasses
import functools
import math
from typing import NamedTuple

import jax
import jax.numpy as jnp

from jaxenvs.agents.base import Trainer
from jaxenvs.config import ConfigError, require
from jaxenvs.core import BatchedEnv, Env, State

#: number of longest episode lengths a chunk reports (for the course's best-100 score)
TOP_K = 100

#: the most entries (states x actions) a Q-table may have: 2**24, 64 MiB of float32 per
#: seed (every step also touches the whole table once)
MAX_TABLE_ENTRIES = 2**24


@dataclasses.dataclass(frozen=True)
class TabularConfig:
    """Parameters of a tabular agent (the ``agent:`` section of a config file).

    Attributes:
      alpha: learning rate (step size) of the TD update, in (0, 1].
      gamma: discount factor, in [0, 1].
      epsilon: initial exploration rate, in [0, 1].
      epsilon_discount: epsilon is multiplied by this once per episode (per env).
      epsilon_min: the floor of the epsilon schedule.
      number_splits: bins per observation dimension; one integer for all dimensions or a
        list with one entry per dimension (1 ignores that dimension). The table has
        their product of states times the task's actions entries, at most
        :data:`MAX_TABLE_ENTRIES` (2**24, 64 MiB per seed).
      obs_low, obs_high: the discretiser's bounds, one value per observation dimension.
      num_envs: envs stepping together and updating the one shared table.
      total_steps: training budget in env steps (over all envs) per seed, rounded up to
        whole chunks (a run never trains less than asked).
      chunk_steps: steps per env in one compiled chunk (progress/checkpoint granularity).
      episodes_per_env: if > 0, each env stops learning after this many episodes (the
        course's ``nepisodes`` with one env); training ends once every env is done or
        ``total_steps`` is spent.
    """

    alpha: float = 0.1
    gamma: float = 0.99
    epsilon: float = 1.0
    epsilon_discount: float = 0.99
    epsilon_min: float = 0.05
    number_splits: int | tuple[int, ...] = 10
    obs_low: tuple[float, ...] | None = None
    obs_high: tuple[float, ...] | None = None
    num_envs: int = 16
    total_steps: int = 200_000
    chunk_steps: int = 500
    episodes_per_env: int = 0

    def validate(self) -> None:
        require(0.0 < self.alpha <= 1.0, "alpha", "must be in (0, 1]")
        require(0.0 <= self.gamma <= 1.0, "gamma", "must be in [0, 1]")
        require(0.0 <= self.epsilon <= 1.0, "epsilon", "must be in [0, 1]")
        require(0.0 < self.epsilon_discount <= 1.0, "epsilon_discount", "must be in (0, 1]")
        require(0.0 <= self.epsilon_min <= 1.0, "epsilon_min", "must be in [0, 1]")
        splits = (
            (self.number_splits,) if isinstance(self.number_splits, int) else self.number_splits
        )
        require(len(splits) > 0, "number_splits", "must not be empty")
        require(all(n >= 1 for n in splits), "number_splits", "must be >= 1")
        if not isinstance(self.number_splits, int):
            check_table_size(math.prod(splits), None)
        for name in ("obs_low", "obs_high"):
            value = getattr(self, name)
            require(value is None or len(value) > 0, name, "must not be empty")
        if self.obs_low is not None and self.obs_high is not None:
            require(len(self.obs_low) == len(self.obs_high), "obs_high", "must match obs_low")
            require(
                all(lo < hi for lo, hi in zip(self.obs_low, self.obs_high, strict=True)),
                "obs_high",
                "must exceed obs_low in every dimension",
            )
        require(self.num_envs >= 1, "num_envs", "must be >= 1")
        require(self.total_steps >= 1, "total_steps", "must be >= 1")
        require(self.chunk_steps >= 1, "chunk_steps", "must be >= 1")
        require(self.episodes_per_env >= 0, "episodes_per_env", "must be >= 0")


@dataclasses.dataclass(frozen=True)
class QLearningConfig(TabularConfig):
    """Q-learning (off-policy: bootstraps from the greedy value of the next state)."""


@dataclasses.dataclass(frozen=True)
class SarsaConfig(TabularConfig):
    """SARSA (on-policy: bootstraps from the action actually taken next)."""


def check_table_size(num_states: int, num_actions: int | None) -> None:
    """ConfigError naming ``number_splits`` unless a table of ``num_states`` x
    ``num_actions`` entries (at least ``num_states`` when the actions are not known yet)
    is within :data:`MAX_TABLE_ENTRIES`."""
    entries = num_states * (num_actions or 1)
    if entries <= MAX_TABLE_ENTRIES:
        return
    limit = f"the limit is {MAX_TABLE_ENTRIES} entries ({MAX_TABLE_ENTRIES * 4 // 2**20} MiB)"
    if num_actions is None:
        raise ConfigError(
            f"key 'number_splits' gives {num_states} states, more Q-table entries than "
            f"allowed per seed: {limit}"
        )
    raise ConfigError(
        f"key 'number_splits' gives a Q-table of {num_states} states x {num_actions} "
        f"actions = {entries} entries ({entries * 4 / 2**20:.0f} MiB per seed); {limit}"
    )


class Discretiser(NamedTuple):
    """Uniform bins: ``splits`` per dimension between ``low`` and ``high``."""

    low: jax.Array
    high: jax.Array
    splits: jax.Array  # int32 (obs_dim,)
    strides: jax.Array  # int32 (obs_dim,), row-major
    num_states: int


def make_discretiser(
    low: tuple[float, ...], high: tuple[float, ...], splits: int | tuple[int, ...]
) -> Discretiser:
    """A :class:`Discretiser`; ``splits`` is one count for all dimensions or one each."""
    dim = len(low)
    per_dim = (splits,) * dim if isinstance(splits, int) else tuple(splits)
    if len(per_dim) != dim or len(high) != dim:
        raise ConfigError(
            f"number_splits, obs_low and obs_high need one entry per observation dimension "
            f"({dim}); got {len(per_dim)}, {len(low)}, {len(high)}"
        )
    strides = [math.prod(per_dim[i + 1 :]) for i in range(dim)]
    return Discretiser(
        low=jnp.asarray(low, jnp.float32),
        high=jnp.asarray(high, jnp.float32),
        splits=jnp.asarray(per_dim, jnp.int32),
        strides=jnp.asarray(strides, jnp.int32),
        num_states=math.prod(per_dim),
    )


def bin_index(disc: Discretiser, obs: jax.Array) -> jax.Array:
    """Per-dimension bin of one observation; outside values land in the edge bins."""
    frac = (obs - disc.low) / (disc.high - disc.low)
    idx = jnp.floor(frac * disc.splits).astype(jnp.int32)
    return jnp.clip(idx, 0, disc.splits - 1)


def state_index(disc: Discretiser, obs: jax.Array) -> jax.Array:
    """The table row of one observation (int32 scalar)."""
    return jnp.sum(bin_index(disc, obs) * disc.strides)


def epsilon_at(config: TabularConfig, episodes: jax.Array) -> jax.Array:
    """Epsilon after ``episodes`` finished episodes: decayed per episode, floored."""
    eps = config.epsilon * jnp.power(config.epsilon_discount, episodes.astype(jnp.float32))
    return jnp.maximum(eps, config.epsilon_min)


def greedy_action(q_row: jax.Array, key: jax.Array) -> jax.Array:
    """Argmax of one table row, ties broken uniformly at random."""
    noise = jax.random.uniform(key, q_row.shape)
    return jnp.argmax(jnp.where(q_row == jnp.max(q_row), noise, -1.0)).astype(jnp.int32)


def epsilon_greedy(q_row: jax.Array, epsilon: jax.Array, key: jax.Array) -> jax.Array:
    """With probability ``epsilon`` a uniform action, else :func:`greedy_action`."""
    explore_key, random_key, tie_key = jax.random.split(key, 3)
    random_action = jax.random.randint(random_key, (), 0, q_row.shape[0], jnp.int32)
    explore = jax.random.uniform(explore_key) < epsilon
    return jnp.where(explore, random_action, greedy_action(q_row, tie_key))


def td_errors(
    q: jax.Array,
    s: jax.Array,
    a: jax.Array,
    reward: jax.Array,
    terminated: jax.Array,
    bootstrap: jax.Array,
    gamma: float,
) -> jax.Array:
    """``r + gamma * bootstrap * (1 - terminated) - Q(s, a)`` per env (batched inputs)."""
    target = reward + gamma * jnp.where(terminated, 0.0, bootstrap)
    return target - q[s, a]


def shared_update(
    q: jax.Array,
    s: jax.Array,
    a: jax.Array,
    delta: jax.Array,
    mask: jax.Array,
    alpha: float,
) -> jax.Array:
    """Apply N envs' TD errors to one table: each hit entry moves by alpha x their mean.

    ``mask`` (bool, per env) drops envs that should not learn this step.
    """
    num_actions = q.shape[1]
    flat = s * num_actions + a
    weight = mask.astype(q.dtype)
    sums = jnp.zeros(q.size, q.dtype).at[flat].add(delta * weight)
    counts = jnp.zeros(q.size, q.dtype).at[flat].add(weight)
    step = jnp.where(counts > 0, sums / jnp.maximum(counts, 1.0), 0.0)
    return q + alpha * step.reshape(q.shape)


def q_learning_bootstrap(q: jax.Array, s_next: jax.Array) -> jax.Array:
    """``max_b Q(s', b)`` per env."""
    return jnp.max(q[s_next], axis=-1)


class TabularState(NamedTuple):
    """Runner state of a tabular agent (one seed).

    Attributes:
      q: the shared Q-table ``(num_states, num_actions)``.
      env_state: the batched env state (``num_envs`` leading axis).
      action: the action each env takes next (SARSA's ``a'``; Q-learning redraws it).
      episodes: finished episodes per env (drives that env's epsilon).
      env_steps: env steps taken while learning, over all envs.
      key: the agent's PRNG key.
    """

    q: jax.Array
    env_state: State
    action: jax.Array
    episodes: jax.Array
    env_steps: jax.Array
    key: jax.Array


def episode_metrics(
    done: jax.Array, final_return: jax.Array, final_length: jax.Array
) -> dict[str, jax.Array]:
    """Chunk metrics from per-step arrays ``(T, N)`` of finished-episode flags and stats.

    Returns ``mean_return``, ``max_return``, ``mean_length`` (nan when no episode ended),
    ``episodes_in_chunk``, ``sum_length`` and ``top_lengths`` (the ``TOP_K`` longest
    lengths, -1 padded), from which the runner computes the overall and best-100 scores.
    """
    n = jnp.sum(done)
    nan = jnp.float32(jnp.nan)
    denom = jnp.maximum(n, 1).astype(jnp.float32)
    lengths = final_length.astype(jnp.float32)
    sum_ret = jnp.sum(jnp.where(done, final_return, 0.0))
    sum_len = jnp.sum(jnp.where(done, lengths, 0.0))
    max_ret = jnp.max(jnp.where(done, final_return, -jnp.inf))
    flat = jnp.where(done, lengths, -1.0).reshape(-1)
    k = min(TOP_K, flat.shape[0])
    top = jax.lax.top_k(flat, k)[0]
    top = jnp.concatenate([top, -jnp.ones(TOP_K - k, jnp.float32)])
    return {
        "mean_return": jnp.where(n > 0, sum_ret / denom, nan),
        "max_return": jnp.where(n > 0, max_ret, nan),
        "mean_length": jnp.where(n > 0, sum_len / denom, nan),
        "episodes_in_chunk": n.astype(jnp.int32),
        "sum_length": sum_len,
        "top_lengths": top,
    }


def _check_env(env: Env, config: TabularConfig) -> tuple[tuple[float, ...], tuple[float, ...]]:
    if not env.discrete:
        raise ConfigError(
            f"tabular agents need a discrete-action task; {type(env).__name__} has continuous "
            f"actions Box({env.action_size}) (use --algo ppo)"
        )
    if config.obs_low is None or config.obs_high is None:
        raise ConfigError(
            "tabular agents need the discretiser bounds: set agent.obs_low and agent.obs_high "
            f"({env.observation_size} values each)"
        )
    if len(config.obs_low) != env.observation_size:
        raise ConfigError(
            f"key 'obs_low' has {len(config.obs_low)} values but the observation has "
            f"{env.observation_size} dimensions"
        )
    splits = config.number_splits
    if not isinstance(splits, int) and len(splits) != env.observation_size:
        raise ConfigError(
            f"key 'number_splits' has {len(splits)} values but the observation has "
            f"{env.observation_size} dimensions"
        )
    dims = env.observation_size
    per_dim = (splits,) * dims if isinstance(splits, int) else splits
    check_table_size(math.prod(per_dim), env.action_size)
    return config.obs_low, config.obs_high


def _chunk_metrics(
    config: TabularConfig, ts: TabularState, out: tuple[jax.Array, ...], active: jax.Array
) -> dict[str, jax.Array]:
    """A chunk's metrics from its steps' ``(finished, final return, final length,
    diverged)`` and the training state after it (``active``: the envs still learning)."""
    done, ret, length, diverged = out
    metrics = episode_metrics(done, ret, length)
    metrics["diverged"] = jnp.sum(diverged).astype(jnp.int32)
    metrics["env_steps"] = ts.env_steps
    metrics["episodes"] = jnp.sum(ts.episodes)
    metrics["epsilon"] = jnp.mean(epsilon_at(config, ts.episodes))
    metrics["active_envs"] = jnp.sum(active).astype(jnp.int32)
    return metrics


def _greedy(disc: Discretiser, q: jax.Array, obs: jax.Array, key: jax.Array) -> jax.Array:
    """The greedy action of the table ``q`` at ``obs`` (ties broken by ``key``)."""
    return greedy_action(q[state_index(disc, obs)], key)


def make_trainer(env: Env, config: TabularConfig) -> Trainer:
    """The Q-learning (``QLearningConfig``) or SARSA (``SarsaConfig``) trainer on ``env``.

    ``steps_per_chunk`` is ``chunk_steps * num_envs`` env steps; ``num_chunks`` covers
    ``total_steps``. Chunk metrics add ``epsilon`` (mean over envs), ``sum_length``,
    ``top_lengths``, ``active_envs`` and ``diverged`` (episodes ended by physics
    divergence) to :data:`jaxenvs.agents.base.CHUNK_METRICS`.
    """
    low, high = _check_env(env, config)
    sarsa, num_actions = isinstance(config, SarsaConfig), env.action_size
    disc = make_discretiser(low, high, config.number_splits)
    # one device here: the runner spreads the whole training state (jaxenvs.core.sharding)
    # vmapped over seeds: a compact reset's loop would run the most chunks any seed needs
    benv = BatchedEnv(env, config.num_envs, devices=1, compact_reset=False)
    n = config.num_envs
    gamma, alpha = config.gamma, config.alpha
    limit = config.episodes_per_env

    def choose(q: jax.Array, s: jax.Array, eps: jax.Array, key: jax.Array) -> jax.Array:
        return jax.vmap(epsilon_greedy)(q[s], eps, jax.random.split(key, n))

    def states_of(obs: jax.Array) -> jax.Array:
        return jax.vmap(lambda o: state_index(disc, o))(obs)

    def active_mask(episodes: jax.Array) -> jax.Array:
        if limit > 0:
            return episodes < limit
        return jnp.ones_like(episodes, bool)

    def init(key: jax.Array) -> TabularState:
        env_key, act_key, agent_key = jax.random.split(key, 3)
        env_state = benv.reset(env_key)
        q = jnp.zeros((disc.num_states, num_actions), jnp.float32)
        episodes = jnp.zeros(n, jnp.int32)
        action = choose(q, states_of(env_state.obs), epsilon_at(config, episodes), act_key)
        return TabularState(q, env_state, action, episodes, jnp.zeros((), jnp.int32), agent_key)

    def step(
        ts: TabularState, _: None
    ) -> tuple[TabularState, tuple[jax.Array, jax.Array, jax.Array, jax.Array]]:
        key, act_key, next_key, boot_key = jax.random.split(ts.key, 4)
        s = states_of(ts.env_state.obs)
        active = active_mask(ts.episodes)
        if sarsa:
            action = ts.action
        else:
            action = choose(ts.q, s, epsilon_at(config, ts.episodes), act_key)
        nxt = benv.step(ts.env_state, action)
        done = nxt.done
        episodes = ts.episodes + (done & active).astype(jnp.int32)
        eps = epsilon_at(config, episodes)
        s_final = states_of(nxt.info["final_obs"])
        if sarsa:
            next_action = choose(ts.q, states_of(nxt.obs), eps, next_key)
            boot_action = jnp.where(done, choose(ts.q, s_final, eps, boot_key), next_action)
            bootstrap = ts.q[s_final, boot_action]
        else:
            next_action = action
            bootstrap = q_learning_bootstrap(ts.q, s_final)
        delta = td_errors(ts.q, s, action, nxt.reward, nxt.terminated, bootstrap, gamma)
        q = shared_update(ts.q, s, action, delta, active, alpha)
        env_steps = ts.env_steps + jnp.sum(active).astype(jnp.int32)
        finished = done & active
        out = (finished, nxt.info["final_return"], nxt.info["final_length"])
        diverged = nxt.info["diverged"] & active
        return TabularState(q, nxt, next_action, episodes, env_steps, key), (*out, diverged)

    def chunk(ts: TabularState) -> tuple[TabularState, dict[str, jax.Array]]:
        ts, out = jax.lax.scan(step, ts, None, length=config.chunk_steps)
        return ts, _chunk_metrics(config, ts, out, active_mask(ts.episodes))

    per_chunk = config.chunk_steps * n
    return Trainer(
        init=init,
        chunk=chunk,
        policy_params=lambda ts: ts.q,
        act=functools.partial(_greedy, disc),
        steps_per_chunk=per_chunk,
        num_chunks=max(1, -(-config.total_steps // per_chunk)),
    )
