"""A PPO rollout: one step of every env under the behaviour policy, the rollout of
``num_steps`` of them with its normaliser statistics, and the episode figures of a
rollout and of a chunk."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any, NamedTuple, cast

import jax
import jax.numpy as jnp

from jaxenvs.agents.networks import ActorCritic
from jaxenvs.agents.normalize import RunningStats, merge_sums, shifted_sums, stats_empty
from jaxenvs.agents.normalize import stats_update as _stats_update
from jaxenvs.agents.ppo.config import PPOConfig
from jaxenvs.agents.ppo.devices import Devices
from jaxenvs.agents.ppo.policy import (
    PolicyHead,
    RunnerState,
    Transition,
    apply_net,
    critic_inputs,
    observe,
    observe_critic,
)
from jaxenvs.core import BatchedEnv

EnvStep = Callable[[RunnerState, jax.Array], tuple[RunnerState, Transition]]


def make_env_step(
    benv: BatchedEnv, net: ActorCritic, head: PolicyHead, config: PPOConfig
) -> EnvStep:
    """``env_step(rs, key) -> (rs, transition)``: one step of every env of ``benv`` under
    the behaviour policy, with the observation and reward statistics it updates."""
    c = config

    def env_step(rs: RunnerState, key: jax.Array) -> tuple[RunnerState, Transition]:
        state = rs.env_state
        obs = observe(rs.obs_stats, state.obs, c)
        extra = critic_inputs(state.info, c.critic_info, state.time == 0)
        extra = observe_critic(rs.critic_stats, extra, c)
        out, value = apply_net(net, rs.params, obs, extra)
        action = head.sample(out, key)
        logp = head.log_prob(out, action)
        env_action = action if benv.env.discrete else jnp.clip(action, -1.0, 1.0)
        nxt = benv.step(rs.env_state, env_action)
        obs_stats = _stats_update(rs.obs_stats, nxt.obs) if c.normalize_obs else rs.obs_stats
        critic_stats = rs.critic_stats
        if critic_stats is not None and c.normalize_obs:
            fresh = critic_inputs(nxt.info, c.critic_info, nxt.time == 0)
            critic_stats = _stats_update(critic_stats, fresh)
        final_extra = critic_inputs(nxt.info, c.critic_info, nxt.terminated)
        _, next_value = apply_net(
            net,
            rs.params,
            observe(obs_stats, nxt.info["final_obs"], c),
            observe_critic(critic_stats, final_extra, c),
        )
        reward = nxt.reward * c.reward_scale
        disc_return = rs.disc_return * c.gamma + reward
        ret_stats = rs.ret_stats
        if c.normalize_rewards:
            ret_stats = _stats_update(ret_stats, disc_return)
            reward = reward / jnp.sqrt(ret_stats.var + 1e-8)
        done = nxt.done
        trans = Transition(
            obs=obs,
            critic_extra=extra,
            action=action,
            log_prob=logp,
            value=value,
            next_value=next_value,
            reward=reward,
            terminated=nxt.terminated,
            done=done,
            final_return=nxt.info["final_return"],
            final_length=nxt.info["final_length"],
            diverged=nxt.info["diverged"],
        )
        rs = rs._replace(
            obs_stats=obs_stats,
            critic_stats=critic_stats,
            ret_stats=ret_stats,
            disc_return=jnp.where(done, 0.0, disc_return),
            env_state=nxt,
        )
        return rs, trans

    return env_step


def episode_stats(traj: Transition) -> dict[str, jax.Array]:
    """The episodes that ended in a rollout: their number ``n``, the sum and maximum of
    their returns, the sum of their lengths, and the steps that diverged."""
    done = traj.done
    return {
        "n": done.sum(),
        "ret_sum": jnp.sum(jnp.where(done, traj.final_return, 0.0)),
        "ret_max": jnp.max(jnp.where(done, traj.final_return, -jnp.inf)),
        "len_sum": jnp.sum(jnp.where(done, traj.final_length, 0)),
        "diverged": jnp.sum(traj.diverged).astype(jnp.int32),
    }


#: the loss figures a chunk reports (those of its last update)
LOSS_METRICS = ("loss", "policy_loss", "value_loss", "entropy", "approx_kl")


def chunk_metrics(rs: RunnerState, m: dict[str, jax.Array]) -> dict[str, jax.Array]:
    """A chunk's metrics from the state after it and its updates' :func:`episode_stats`
    and loss figures stacked over updates (means are NaN when no episode ended)."""
    n = m["n"].sum()
    nan = jnp.asarray(jnp.nan, jnp.float32)
    return {
        "env_steps": rs.env_steps,
        "episodes": rs.episodes,
        "mean_return": jnp.where(n > 0, m["ret_sum"].sum() / jnp.maximum(n, 1), nan),
        "max_return": jnp.where(n > 0, m["ret_max"].max(), nan),
        "mean_length": jnp.where(n > 0, m["len_sum"].sum() / jnp.maximum(n, 1), nan),
        "episodes_in_chunk": n.astype(jnp.int32),
        "diverged": m["diverged"].sum(),
        **{k: m[k][-1] for k in LOSS_METRICS},
    }


class _Shares(NamedTuple):
    """One device's own samples of a rollout, for the statistics it merges at the end
    (``None``: statistics that the config does not keep)."""

    obs: RunningStats | None
    critic: RunningStats | None
    ret: RunningStats | None


Collect = Callable[[RunnerState, jax.Array], tuple[RunnerState, Transition, dict[str, Any]]]


def make_collect(env_step: EnvStep, config: PPOConfig, devices: Devices) -> Collect:
    """``collect(rs, key) -> (rs, trajectory, episode_stats)``: ``num_steps`` steps of
    :func:`make_env_step`'s ``env_step`` (a key each, from ``key``) and the rollout's
    :func:`episode_stats`.

    On one device that is all. On several, each device steps its own envs with its own
    key (``key`` is this device's) and its statistics move with its own envs'
    observations during the rollout; at its end the devices meet once: one ``psum``
    merges every device's samples into the statistics they shared at its start and adds
    up the episode figures, one ``pmax`` takes the best return. Every device then holds
    the statistics of all the rollout's samples and the episodes of all its envs.
    """
    c = config
    if not devices.parallel:

        def collect_one(rs: RunnerState, key: jax.Array) -> Any:
            rs, traj = jax.lax.scan(env_step, rs, jax.random.split(key, c.num_steps))
            return rs, traj, episode_stats(traj)

        return collect_one

    def share(stats: RunningStats | None, on: bool) -> RunningStats | None:
        return stats_empty(stats.mean.shape) if stats is not None and on else None

    def grow(acc: RunningStats | None, batch: Any) -> RunningStats | None:
        return None if acc is None else _stats_update(acc, batch())

    def step(carry: tuple[RunnerState, _Shares], key: jax.Array) -> Any:
        rs, acc = carry
        nxt, trans = env_step(rs, key)
        s = nxt.env_state
        disc = lambda: rs.disc_return * c.gamma + s.reward * c.reward_scale  # noqa: E731
        acc = _Shares(
            grow(acc.obs, lambda: s.obs),
            grow(acc.critic, lambda: critic_inputs(s.info, c.critic_info, s.time == 0)),
            grow(acc.ret, disc),
        )
        return (nxt, acc), trans

    def collect(rs: RunnerState, key: jax.Array) -> Any:
        start = rs
        acc = _Shares(
            share(rs.obs_stats, c.normalize_obs),
            share(rs.critic_stats, c.normalize_obs),
            share(rs.ret_stats, c.normalize_rewards),
        )
        (rs, acc), traj = jax.lax.scan(step, (rs, acc), jax.random.split(key, c.num_steps))
        ep = episode_stats(traj)
        bases = (start.obs_stats, start.critic_stats, start.ret_stats)
        sums = [
            None if a is None or b is None else shifted_sums(a, b.mean)
            for a, b in zip(acc, bases, strict=True)
        ]
        totals = ("n", "ret_sum", "len_sum", "diverged")
        sums, added = devices.sum((sums, {k: ep[k] for k in totals}))
        obs, critic, ret = (
            b if s is None or b is None else merge_sums(b, s)
            for b, s in zip(bases, sums, strict=True)
        )
        rs = rs._replace(obs_stats=cast(RunningStats, obs), ret_stats=cast(RunningStats, ret))
        rs = rs._replace(critic_stats=critic)
        return rs, traj, {**added, "ret_max": devices.max(ep["ret_max"])}

    return collect
