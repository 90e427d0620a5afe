"""Proximal Policy Optimisation for every jaxenvs task, as one compiled program.

``make_trainer(env, config)`` returns a :class:`jaxenvs.agents.base.Trainer`; one chunk
runs ``updates_per_chunk`` PPO iterations, each one a rollout of ``num_steps`` steps of
``num_envs`` auto-resetting envs followed by ``update_epochs`` epochs of
``num_minibatches`` shuffled minibatches. ``base.make_train(trainer)`` turns it into a
single ``train(key)`` (one ``jit``); ``vmap`` over keys trains many seeds at once.

What the algorithm does (see also :mod:`jaxenvs.agents.losses`, :mod:`.networks`):

* Bootstrapping: a transition's target uses the value of the state it really ended in,
  ``info["final_obs"]`` (so a *truncated* episode bootstraps from its last observation,
  not from the fresh reset one); a *terminated* one does not bootstrap.
* Observation normalisation: running mean/variance of observations (merged batch by
  batch at every env step) kept in the training state; the policy sees
  ``clip((obs - mean) / std, -obs_clip, obs_clip)``. The rollout stores normalised
  observations, so the update uses exactly what the behaviour policy saw.
* Asymmetric actor-critic: ``critic_info`` names scalar ``info`` entries of the task
  (its metrics: privileged quantities such as the body's measured velocity) that the
  critic sees after the observation and the policy never does. A state's entries are
  those of the transition into it, zero at a fresh start (as a single env's reset
  reports them); a truncated episode's bootstrap reads its last transition's (the
  batched env keeps them through the auto-reset); non-finite entries read as zero. They
  are normalised with their own running statistics under ``normalize_obs``.
* Reward scaling: rewards are multiplied by ``reward_scale``; with ``normalize_rewards``
  they are also divided by the running standard deviation of the discounted return
  (as Stable-Baselines3's ``VecNormalize``).
* Optimiser: Adam (eps 1e-5) after global-norm gradient clipping, learning rate annealed
  linearly to zero over the run when ``anneal_lr``.
* Continuous actions: a Gaussian clipped to [-1, 1] (see :mod:`.networks`); the greedy
  policy is ``clip(mean)``; discrete: ``argmax`` of the logits.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import optax

from jaxenvs.agents import losses
from jaxenvs.agents.base import Trainer
from jaxenvs.agents.networks import (
    ActorCritic,
    categorical_entropy,
    categorical_log_prob,
    gaussian_entropy,
    gaussian_log_prob,
)
from jaxenvs.agents.normalize import RunningStats, normalize, stats_init, stats_update
from jaxenvs.config import require
from jaxenvs.core import BatchedEnv, Env, State

PyTree = Any


@dataclasses.dataclass(frozen=True)
class PPOConfig:
    """PPO hyperparameters.

    Attributes:
      total_steps: env steps to train for, rounded up to whole chunks (a run never
        trains less than asked).
      num_envs: parallel envs per seed.
      num_steps: rollout length per env per update.
      updates_per_chunk: PPO iterations per chunk (progress/checkpoint granularity).
      update_epochs: passes over each rollout.
      num_minibatches: minibatches per epoch (must divide num_envs * num_steps).
      learning_rate: Adam step size (initial value when annealed).
      anneal_lr: decay the learning rate linearly to zero over the run.
      max_grad_norm: global-norm gradient clipping.
      gamma, gae_lambda: discount and GAE lambda.
      clip_eps: PPO ratio clip.
      clip_value: also clip the value update (PPO2-style) with ``clip_eps`` (off by
        default: it slowed the critic on returns of O(100) in every task we tuned).
      ent_coef, vf_coef: entropy bonus and value-loss weights.
      normalize_advantages: per-minibatch advantage normalisation.
      normalize_obs: running observation normalisation.
      obs_clip: clip of normalised observations.
      reward_scale: constant reward multiplier.
      normalize_rewards: divide rewards by the running std of the discounted return.
      actor_hidden, critic_hidden: MLP widths (tanh).
      log_std_init: initial log standard deviation (continuous tasks).
      randomize: train on domain-randomised envs (each env draws its physics params from
        the task's ``sample_params`` at every reset).
      critic_info: ``info`` keys (scalar task metrics) the critic also sees (the module
        docstring); empty: the critic sees the observation alone.
    """

    total_steps: int = 500_000
    num_envs: int = 64
    num_steps: int = 64
    updates_per_chunk: int = 4
    update_epochs: int = 4
    num_minibatches: int = 4
    learning_rate: float = 3e-4
    anneal_lr: bool = True
    max_grad_norm: float = 0.5
    gamma: float = 0.99
    gae_lambda: float = 0.95
    clip_eps: float = 0.2
    clip_value: bool = False
    ent_coef: float = 0.0
    vf_coef: float = 0.5
    normalize_advantages: bool = True
    normalize_obs: bool = True
    obs_clip: float = 10.0
    reward_scale: float = 1.0
    normalize_rewards: bool = False
    actor_hidden: tuple[int, ...] = (64, 64)
    critic_hidden: tuple[int, ...] = (64, 64)
    log_std_init: float = 0.0
    randomize: bool = False
    critic_info: tuple[str, ...] = ()

    def validate(self) -> None:
        for name in ("total_steps", "num_envs", "num_steps", "updates_per_chunk"):
            require(getattr(self, name) > 0, name, "must be positive")
        require(self.update_epochs > 0, "update_epochs", "must be positive")
        require(self.num_minibatches > 0, "num_minibatches", "must be positive")
        require(
            (self.num_envs * self.num_steps) % self.num_minibatches == 0,
            "num_minibatches",
            f"must divide num_envs * num_steps ({self.num_envs * self.num_steps})",
        )
        require(self.learning_rate > 0, "learning_rate", "must be positive")
        require(self.max_grad_norm > 0, "max_grad_norm", "must be positive")
        require(0.0 <= self.gamma <= 1.0, "gamma", "must lie in [0, 1]")
        require(0.0 <= self.gae_lambda <= 1.0, "gae_lambda", "must lie in [0, 1]")
        require(self.clip_eps > 0, "clip_eps", "must be positive")
        require(self.ent_coef >= 0, "ent_coef", "must be >= 0")
        require(self.vf_coef >= 0, "vf_coef", "must be >= 0")
        require(self.obs_clip > 0, "obs_clip", "must be positive")
        require(self.reward_scale > 0, "reward_scale", "must be positive")
        require(all(w > 0 for w in self.actor_hidden), "actor_hidden", "widths must be > 0")
        require(all(w > 0 for w in self.critic_hidden), "critic_hidden", "widths must be > 0")
        require(
            len(set(self.critic_info)) == len(self.critic_info), "critic_info", "has duplicates"
        )

    @property
    def steps_per_update(self) -> int:
        return self.num_envs * self.num_steps

    @property
    def steps_per_chunk(self) -> int:
        return self.steps_per_update * self.updates_per_chunk

    @property
    def num_chunks(self) -> int:
        return max(1, -(-self.total_steps // self.steps_per_chunk))


#: the config the runner builds when no file is given (``--algo ppo``).
DEFAULT_CONFIG = PPOConfig()


# ------------------------------------------------------------------------ the trainer
class RunnerState(NamedTuple):
    """Everything one seed's training carries between chunks."""

    params: PyTree
    opt_state: PyTree
    obs_stats: RunningStats
    ret_stats: RunningStats
    disc_return: jax.Array  # (num_envs,) running discounted return (reward normalisation)
    env_state: State
    key: jax.Array
    env_steps: jax.Array
    episodes: jax.Array
    updates: jax.Array
    #: running statistics of the critic's ``critic_info`` inputs (``None`` without them)
    critic_stats: RunningStats | None = None


class PolicyParams(NamedTuple):
    """What the greedy policy needs: network params and the observation statistics."""

    params: PyTree
    obs_stats: RunningStats


class Transition(NamedTuple):
    obs: jax.Array
    critic_extra: jax.Array  # (..., len(critic_info)) as the critic saw them
    action: jax.Array
    log_prob: jax.Array
    value: jax.Array
    next_value: jax.Array
    reward: jax.Array
    terminated: jax.Array
    done: jax.Array
    final_return: jax.Array
    final_length: jax.Array
    diverged: jax.Array


def _sample_categorical(out: Any, key: jax.Array) -> jax.Array:
    return jax.random.categorical(key, out).astype(jnp.int32)


def _mode_categorical(out: Any) -> jax.Array:
    return jnp.argmax(out, axis=-1).astype(jnp.int32)


def _sample_gaussian(out: Any, key: jax.Array) -> jax.Array:
    mean, log_std = out
    return mean + jnp.exp(log_std) * jax.random.normal(key, mean.shape)


def _mode_gaussian(out: Any) -> jax.Array:
    return jnp.clip(out[0], -1.0, 1.0)


class PolicyHead(NamedTuple):
    """The distribution functions of one kind of policy output."""

    sample: Callable[[Any, jax.Array], jax.Array]
    log_prob: Callable[[Any, jax.Array], jax.Array]
    entropy: Callable[[Any], jax.Array]
    mode: Callable[[Any], jax.Array]


CATEGORICAL = PolicyHead(
    _sample_categorical, categorical_log_prob, categorical_entropy, _mode_categorical
)
GAUSSIAN = PolicyHead(
    _sample_gaussian,
    lambda out, a: gaussian_log_prob(out[0], out[1], a),
    lambda out: gaussian_entropy(out[1]),
    _mode_gaussian,
)


def make_network(env: Env, config: PPOConfig) -> ActorCritic:
    return ActorCritic(
        action_size=env.action_size,
        discrete=env.discrete,
        actor_hidden=config.actor_hidden,
        critic_hidden=config.critic_hidden,
        log_std_init=config.log_std_init,
    )


def make_optimizer(config: PPOConfig) -> optax.GradientTransformation:
    """Adam (eps 1e-5) after global-norm gradient clipping; with ``anneal_lr`` its step
    size falls linearly to zero over every gradient step of the run."""
    c = config
    total_grad_steps = c.num_chunks * c.updates_per_chunk * c.update_epochs * c.num_minibatches
    lr: float | optax.Schedule = (
        optax.linear_schedule(c.learning_rate, 0.0, total_grad_steps)
        if c.anneal_lr
        else c.learning_rate
    )
    return optax.chain(optax.clip_by_global_norm(c.max_grad_norm), optax.adam(lr, eps=1e-5))


def shuffle_minibatches(key: jax.Array, data: PyTree, num_minibatches: int) -> PyTree:
    """One epoch's minibatches of a time-major rollout.

    Every leaf of ``data`` has shape ``(T, N, ...)``. Its ``T * N`` samples are flattened,
    shuffled by ONE permutation drawn from ``key`` (the same for every leaf, so a sample's
    fields stay together) and cut into ``num_minibatches`` equal minibatches: every leaf
    becomes ``(num_minibatches, T * N // num_minibatches, ...)``, and each sample appears
    exactly once. ``num_minibatches`` must divide ``T * N``.
    """
    first = jax.tree.leaves(data)[0]
    n = first.shape[0] * first.shape[1]

    perm = jax.random.permutation(key, n)

    def split(x: jax.Array) -> jax.Array:
        x = x.reshape((n, *x.shape[2:]))[perm]
        return x.reshape((num_minibatches, n // num_minibatches, *x.shape[1:]))

    return jax.tree.map(split, data)


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


def apply_net(
    net: ActorCritic, params: PyTree, obs: jax.Array, critic_extra: jax.Array | None = None
) -> tuple[Any, jax.Array]:
    """The network's ``(policy output, value)`` of ``obs`` (and the critic's own inputs;
    ``None`` or an empty last axis: none)."""
    if critic_extra is not None and critic_extra.shape[-1] == 0:
        critic_extra = None
    return net.apply(params, obs, critic_extra)  # type: ignore[return-value]


def critic_inputs(info: dict[str, jax.Array], keys: tuple[str, ...], zero: Any) -> jax.Array:
    """The ``keys`` entries of a batch's ``info`` as ``(num_envs, len(keys))`` float32,
    zero where ``zero`` (per env: a fresh start, or a terminal state whose value is never
    used; ``False``: none) and where not finite (a diverged step's metrics, which the
    env does not clean as it cleans the observation)."""
    if not keys:
        return jnp.zeros((info["episode_length"].shape[0], 0), jnp.float32)
    x = jnp.stack([info[k].astype(jnp.float32) for k in keys], axis=-1)
    return jnp.where(jnp.asarray(zero)[..., None] | ~jnp.isfinite(x), 0.0, x)


def observe_critic(stats: RunningStats | None, x: jax.Array, config: PPOConfig) -> jax.Array:
    """What the critic sees of its ``critic_info`` inputs ``x`` (as :func:`observe`)."""
    return x if stats is None or not config.normalize_obs else normalize(stats, x, config.obs_clip)


def observe(stats: RunningStats, obs: jax.Array, config: PPOConfig) -> jax.Array:
    """What the policy sees of ``obs``: normalised and clipped with ``stats`` when
    ``normalize_obs``, else ``obs`` itself."""
    return normalize(stats, obs, config.obs_clip) if config.normalize_obs else obs


def make_env_step(
    benv: BatchedEnv, net: ActorCritic, head: PolicyHead, config: PPOConfig
) -> Callable[[RunnerState, jax.Array], tuple[RunnerState, Transition]]:
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
        obs_stats = stats_update(rs.obs_stats, nxt.obs) if c.normalize_obs else rs.obs_stats
        critic_stats = rs.critic_stats
        if critic_stats is not None and c.normalize_obs:
            fresh = critic_inputs(nxt.info, c.critic_info, nxt.time == 0)
            critic_stats = stats_update(critic_stats, fresh)
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
            ret_stats = stats_update(ret_stats, disc_return)
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


#: an epoch's carry: network params, optimiser state, and the rollout
#: ``(transitions, advantages, returns)`` it passes over
EpochCarry = tuple[PyTree, PyTree, tuple[Transition, jax.Array, jax.Array]]


def make_epoch(
    net: ActorCritic, head: PolicyHead, tx: optax.GradientTransformation, config: PPOConfig
) -> Callable[[EpochCarry, jax.Array], tuple[EpochCarry, dict[str, jax.Array]]]:
    """``epoch(carry, key) -> (carry, stats)``: one pass over a rollout in
    :func:`shuffle_minibatches` order, one gradient step of :func:`losses.ppo_loss` per
    minibatch; ``stats`` holds each step's loss figures."""
    c = config

    def loss_fn(
        params: PyTree, batch: Transition, adv: jax.Array, ret: jax.Array
    ) -> tuple[jax.Array, dict[str, jax.Array]]:
        out, value = apply_net(net, params, batch.obs, batch.critic_extra)
        logp = head.log_prob(out, batch.action)
        return losses.ppo_loss(
            logp,
            batch.log_prob,
            adv,
            value,
            batch.value,
            ret,
            head.entropy(out),
            clip_eps=c.clip_eps,
            clip_value=c.clip_value,
            vf_coef=c.vf_coef,
            ent_coef=c.ent_coef,
            normalize_adv=c.normalize_advantages,
        )

    grad_fn = jax.value_and_grad(loss_fn, has_aux=True)

    def sgd_step(
        carry: tuple[PyTree, PyTree], mb: tuple[Transition, jax.Array, jax.Array]
    ) -> tuple[tuple[PyTree, PyTree], dict[str, jax.Array]]:
        params, opt_state = carry
        batch, adv, ret = mb
        (loss, aux), grads = grad_fn(params, batch, adv, ret)
        updates, opt_state = tx.update(grads, opt_state, params)
        params = optax.apply_updates(params, updates)
        return (params, opt_state), {"loss": loss, **aux}

    def epoch(carry: EpochCarry, key: jax.Array) -> tuple[EpochCarry, dict[str, jax.Array]]:
        params, opt_state, data = carry
        minibatches = shuffle_minibatches(key, data, c.num_minibatches)
        (params, opt_state), stats = jax.lax.scan(sgd_step, (params, opt_state), minibatches)
        return (params, opt_state, data), stats

    return epoch


def make_trainer(env: Env | BatchedEnv, config: PPOConfig) -> Trainer:
    """The PPO :class:`Trainer` of ``env`` (a single env; a batched one is unwrapped)."""
    config.validate()
    single: Env = env.env if isinstance(env, BatchedEnv) else env
    # one device here: the runner spreads the whole training state (jaxenvs.core.sharding)
    # the runner vmaps the chunk over seeds, under which a compact reset's loop would run
    # every seed through the most chunks any needs (BatchedEnv, "What a step resets")
    benv = BatchedEnv(
        single, config.num_envs, randomize=config.randomize, devices=1, compact_reset=False
    )
    net = make_network(single, config)
    head = CATEGORICAL if single.discrete else GAUSSIAN
    c = config
    tx = make_optimizer(c)
    obs_dim = single.observation_size
    keys = c.critic_info
    known = tuple(single.metric_keys)
    unknown = [k for k in keys if k not in known]
    if unknown:
        raise ValueError(
            f"critic_info: {', '.join(unknown)} not among {type(single).__name__}'s metrics "
            f"({', '.join(known) or 'none'})"
        )
    env_step = make_env_step(benv, net, head, c)
    epoch = make_epoch(net, head, tx, c)

    def init(key: jax.Array) -> RunnerState:
        net_key, env_key, run_key = jax.random.split(key, 3)
        extra = jnp.zeros((len(keys),), jnp.float32) if keys else None
        params = net.init(net_key, jnp.zeros((obs_dim,), jnp.float32), extra)
        env_state = benv.reset(env_key)
        obs_stats = stats_init((obs_dim,))
        critic_stats = stats_init((len(keys),)) if keys else None
        if c.normalize_obs:
            obs_stats = stats_update(obs_stats, env_state.obs)
            if critic_stats is not None:
                critic_stats = stats_update(critic_stats, critic_inputs(env_state.info, keys, True))
        return RunnerState(
            params=params,
            opt_state=tx.init(params),
            obs_stats=obs_stats,
            ret_stats=stats_init(()),
            disc_return=jnp.zeros((c.num_envs,), jnp.float32),
            env_state=env_state,
            key=run_key,
            env_steps=jnp.zeros((), jnp.int32),
            episodes=jnp.zeros((), jnp.int32),
            updates=jnp.zeros((), jnp.int32),
            critic_stats=critic_stats,
        )

    def update(rs: RunnerState, _: None) -> tuple[RunnerState, dict[str, jax.Array]]:
        key, rollout_key, epoch_key = jax.random.split(rs.key, 3)
        rs = rs._replace(key=key)
        rs, traj = jax.lax.scan(env_step, rs, jax.random.split(rollout_key, c.num_steps))
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
            jax.random.split(epoch_key, c.update_epochs),
        )
        ep = episode_stats(traj)
        rs = rs._replace(
            params=params,
            opt_state=opt_state,
            env_steps=rs.env_steps + c.steps_per_update,
            episodes=rs.episodes + ep["n"].astype(jnp.int32),
            updates=rs.updates + 1,
        )
        return rs, {**ep, **{k: v[-1].mean() for k, v in stats.items()}}

    def chunk(rs: RunnerState) -> tuple[RunnerState, dict[str, jax.Array]]:
        rs, m = jax.lax.scan(update, rs, None, length=c.updates_per_chunk)
        return rs, chunk_metrics(rs, m)

    def policy_params(rs: RunnerState) -> PolicyParams:
        return PolicyParams(rs.params, rs.obs_stats)

    def act(pp: PolicyParams, obs: jax.Array, key: jax.Array) -> jax.Array:
        del key  # the greedy policy is deterministic
        out = net.apply(pp.params, observe(pp.obs_stats, obs, c), method="policy")
        return head.mode(out)

    return Trainer(
        init=init,
        chunk=chunk,
        policy_params=policy_params,
        act=act,
        steps_per_chunk=c.steps_per_chunk,
        num_chunks=c.num_chunks,
    )


__all__ = [
    "DEFAULT_CONFIG",
    "PPOConfig",
    "PolicyParams",
    "RunnerState",
    "chunk_metrics",
    "episode_stats",
    "make_env_step",
    "make_epoch",
    "make_optimizer",
    "make_trainer",
    "shuffle_minibatches",
]
