"""PPO's trainer: ``init``, ``chunk``, the greedy policy, on one device or a mesh of them."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import optax
from jax.sharding import Mesh

from jaxenvs.agents import losses
from jaxenvs.agents.base import Stages, Trainer, chunk_of
from jaxenvs.agents.networks import ActorCritic
from jaxenvs.agents.normalize import stats_init
from jaxenvs.agents.ppo import parallel
from jaxenvs.agents.ppo.config import PPOConfig
from jaxenvs.agents.ppo.devices import Devices
from jaxenvs.agents.ppo.policy import (
    CATEGORICAL,
    GAUSSIAN,
    PolicyParams,
    RunnerState,
    Transition,
    check_critic_info,
    critic_inputs,
    make_network,
    observe,
)
from jaxenvs.agents.ppo.rollout import Collect, chunk_metrics, make_collect, make_env_step
from jaxenvs.agents.ppo.update import make_epoch, make_optimizer
from jaxenvs.core import BatchedEnv, Env


def make_trainer(env: Env | BatchedEnv, config: PPOConfig, mesh: Mesh | None = None) -> Trainer:
    """The PPO :class:`Trainer` of ``env`` (a single env; a batched one is unwrapped).

    Without ``mesh`` (or on a mesh of one device) it is one program on one device. On a
    1-D mesh of several, ``init`` and ``chunk`` are programs per device
    (:mod:`jaxenvs.agents.ppo.parallel`): each device steps its share of the
    :meth:`PPOConfig.on_devices` batch; the state's env batch comes back split over the
    mesh, the rest replicated. Either way they are jittable and ``vmap``-able over seeds.
    """
    config.validate()
    single: Env = env.env if isinstance(env, BatchedEnv) else env
    devices = Devices() if mesh is None else parallel.mesh_devices(mesh)
    c = config.on_devices(devices.size)
    # one device's share: the runner lays the state out (jaxenvs.run.placement), and vmaps
    # the chunk over seeds, under which a compact reset's loop would run every seed
    # through the most chunks any needs (BatchedEnv, "What a step resets")
    benv = BatchedEnv(
        single,
        c.num_envs // devices.size,
        randomize=c.randomize,
        devices=1,
        compact_reset=False,
    )
    net = make_network(single, c)
    head = CATEGORICAL if single.discrete else GAUSSIAN
    tx = make_optimizer(c)
    check_critic_info(single, c.critic_info)
    collect = make_collect(make_env_step(benv, net, head, c), c, devices)
    stages = _make_stages(collect, make_epoch(net, head, tx, c, devices), c, devices)

    def policy_params(rs: RunnerState) -> PolicyParams:
        return PolicyParams(rs.params, rs.obs_stats)

    def act(pp: PolicyParams, obs: jax.Array, key: jax.Array) -> jax.Array:
        del key  # the greedy policy is deterministic
        out = net.apply(pp.params, observe(pp.obs_stats, obs, c), method="policy")
        return head.mode(out)

    trainer = Trainer(
        init=_make_init(benv, net, tx, c, devices),
        chunk=chunk_of(stages),
        policy_params=policy_params,
        act=act,
        steps_per_chunk=c.steps_per_chunk,
        num_chunks=c.num_chunks,
        stages=stages,
    )
    if mesh is None or not devices.parallel:
        return trainer
    return parallel.over_mesh(trainer, mesh, bool(c.critic_info))


def _make_init(
    benv: BatchedEnv,
    net: ActorCritic,
    tx: optax.GradientTransformation,
    config: PPOConfig,
    devices: Devices,
) -> Callable[[jax.Array], RunnerState]:
    """``init(key) -> RunnerState``: the network (the same on every device), this
    device's envs and the statistics of every device's first observations."""
    c, keys, obs_dim = config, config.critic_info, benv.env.observation_size

    def init(key: jax.Array) -> RunnerState:
        net_key, env_key, run_key = jax.random.split(key, 3)
        extra = jnp.zeros((len(keys),), jnp.float32) if keys else None
        params = net.init(net_key, jnp.zeros((obs_dim,), jnp.float32), extra)
        env_state = benv.reset(devices.own_key(env_key))
        obs_stats = stats_init((obs_dim,))
        critic_stats = stats_init((len(keys),)) if keys else None
        if c.normalize_obs:
            obs_stats = devices.stats_update(obs_stats, env_state.obs)
            if critic_stats is not None:
                first = critic_inputs(env_state.info, keys, True)
                critic_stats = devices.stats_update(critic_stats, first)
        return RunnerState(
            params=params,
            opt_state=tx.init(params),
            obs_stats=obs_stats,
            ret_stats=stats_init(()),
            disc_return=jnp.zeros((benv.num_envs,), jnp.float32),
            env_state=env_state,
            key=run_key,
            env_steps=jnp.zeros((), jnp.int32),
            episodes=jnp.zeros((), jnp.int32),
            updates=jnp.zeros((), jnp.int32),
            critic_stats=critic_stats,
        )

    return init


class Batch(NamedTuple):
    """What a PPO update's rollout hands its learning: the trajectory, the rollout's
    episode figures and the key of the update's epochs."""

    traj: Transition
    episodes: dict[str, jax.Array]
    epoch_key: jax.Array


def _make_stages(
    collect: Collect,
    epoch: Callable[..., Any],
    config: PPOConfig,
    devices: Devices,
) -> Stages:
    """A chunk's PPO iterations as :class:`Stages`: ``collect`` a rollout
    (:func:`make_collect`), then ``learn`` from it (its advantages, then ``update_epochs``
    epochs of minibatch steps), each device on its own rollout."""
    c = config

    def collect_stage(rs: RunnerState) -> tuple[RunnerState, Batch]:
        key, rollout_key, epoch_key = jax.random.split(rs.key, 3)
        rs = rs._replace(key=key)
        rs, traj, ep = collect(rs, devices.own_key(rollout_key))
        return rs, Batch(traj, ep, epoch_key)

    def learn(rs: RunnerState, batch: Batch) -> tuple[RunnerState, dict[str, jax.Array]]:
        traj, ep = batch.traj, batch.episodes
        adv, ret = losses.gae(
            traj.reward,
            traj.value,
            traj.next_value,
            traj.terminated,
            traj.done,
            c.gamma,
            c.gae_lambda,
        )
        (params, opt_state, _data), stats = jax.lax.scan(
            epoch,
            (rs.params, rs.opt_state, (traj, adv, ret)),
            jax.random.split(devices.own_key(batch.epoch_key), c.update_epochs),
        )
        rs = rs._replace(
            params=params,
            opt_state=opt_state,
            env_steps=rs.env_steps + c.steps_per_update,
            episodes=rs.episodes + ep["n"].astype(jnp.int32),
            updates=rs.updates + 1,
        )
        return rs, {**ep, **{k: v[-1].mean() for k, v in stats.items()}}

    return Stages(collect_stage, learn, chunk_metrics, c.updates_per_chunk)
