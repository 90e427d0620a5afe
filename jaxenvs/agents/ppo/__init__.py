"""Proximal Policy Optimisation for every jaxenvs task, as one compiled program.

``make_trainer(env, config)`` returns a :class:`jaxenvs.agents.base.Trainer`; one chunk
runs ``updates_per_chunk`` PPO iterations, each one a rollout of ``num_steps`` steps of
``num_envs`` auto-resetting envs followed by ``update_epochs`` epochs of
``num_minibatches`` shuffled minibatches. ``base.make_train(trainer)`` turns it into a
single ``train(key)`` (one ``jit``); ``vmap`` over keys trains many seeds at once.
``make_trainer(env, config, mesh)`` runs it data-parallel over the devices of a 1-D mesh
(:mod:`.parallel`; what changes with the device count: :attr:`PPOConfig.scaling` and
docs/devices.md).

What the algorithm does (see also :mod:`jaxenvs.agents.losses`, :mod:`.networks`):

* Bootstrapping: a transition's target uses the value of the state it really ended in,
  ``info["final_obs"]`` (so a *truncated* episode bootstraps from its last observation,
  not from the fresh reset one); a *terminated* one does not bootstrap.
* Observation normalisation: running mean/variance of observations (merged batch by
  batch at every env step) kept in the training state; the policy sees
  ``clip((obs - mean) / std, -obs_clip, obs_clip)``. The rollout stores normalised
  observations, so the update uses exactly what the behaviour policy saw. Over several
  devices each device's statistics move with its own envs during a rollout, and the
  devices' samples are merged at its end.
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

from jaxenvs.agents.normalize import RunningStats, normalize, stats_init, stats_update
from jaxenvs.agents.ppo.config import DEFAULT_CONFIG, SCALINGS, PPOConfig
from jaxenvs.agents.ppo.devices import Devices
from jaxenvs.agents.ppo.policy import (
    CATEGORICAL,
    GAUSSIAN,
    PolicyHead,
    PolicyParams,
    RunnerState,
    Transition,
    apply_net,
    critic_inputs,
    make_network,
    observe,
    observe_critic,
)
from jaxenvs.agents.ppo.rollout import (
    LOSS_METRICS,
    chunk_metrics,
    episode_stats,
    make_collect,
    make_env_step,
)
from jaxenvs.agents.ppo.trainer import make_trainer
from jaxenvs.agents.ppo.update import EpochCarry, make_epoch, make_optimizer, shuffle_minibatches

__all__ = [
    "CATEGORICAL",
    "DEFAULT_CONFIG",
    "GAUSSIAN",
    "LOSS_METRICS",
    "SCALINGS",
    "Devices",
    "EpochCarry",
    "PPOConfig",
    "PolicyHead",
    "PolicyParams",
    "RunnerState",
    "RunningStats",
    "Transition",
    "apply_net",
    "chunk_metrics",
    "critic_inputs",
    "episode_stats",
    "make_collect",
    "make_env_step",
    "make_epoch",
    "make_network",
    "make_optimizer",
    "make_trainer",
    "normalize",
    "observe",
    "observe_critic",
    "shuffle_minibatches",
    "stats_init",
    "stats_update",
]
