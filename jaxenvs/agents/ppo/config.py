"""PPO's hyperparameters (:class:`PPOConfig`) and what a device count makes of them."""

from __future__ import annotations

import dataclasses

from jaxenvs.config import require

#: how ``num_envs`` meets a device count (:attr:`PPOConfig.scaling`)
SCALINGS = ("strong", "weak")


@dataclasses.dataclass(frozen=True)
class PPOConfig:
    """PPO hyperparameters.

    Attributes:
      total_steps: env steps to train for, over every device, rounded up to whole chunks
        (a run never trains less than asked).
      num_envs: parallel envs per seed: in all (``scaling: strong``) or on each device
        (``scaling: weak``).
      num_steps: rollout length per env per update.
      updates_per_chunk: PPO iterations per chunk (progress/checkpoint granularity).
      update_epochs: passes over each rollout.
      num_minibatches: minibatches per epoch (must divide each device's
        ``envs * num_steps``).
      learning_rate: Adam step size (initial value when annealed).
      anneal_lr: decay the learning rate linearly to zero over the run.
      max_grad_norm: global-norm gradient clipping.
      gamma, gae_lambda: discount and GAE lambda.
      clip_eps: PPO ratio clip.
      clip_value: also clip the value update (PPO2-style) with ``clip_eps`` (off by
        default: it slowed the critic on returns of O(100) in every task we tuned).
      ent_coef, vf_coef: entropy bonus and value-loss weights.
      normalize_advantages: per-minibatch advantage normalisation (over each device's
        share of the minibatch).
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
      scaling: what more devices do with ``num_envs``: ``strong`` (the default) splits
        the same batch over them, so a config trains the same algorithm on any device
        count; ``weak`` gives every device ``num_envs`` envs, so N devices collect N times
        the data per update and reach ``total_steps`` in 1/N of the updates
        (:meth:`on_devices`; docs/devices.md).
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
    scaling: str = "strong"

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
        require(self.scaling in SCALINGS, "scaling", f"must be one of {', '.join(SCALINGS)}")

    def on_devices(self, devices: int) -> PPOConfig:
        """This config as it trains on ``devices`` devices, as a ``strong`` one of the
        whole batch: ``weak`` multiplies ``num_envs`` by ``devices``. Raises
        ``ValueError`` naming the sizes when the batch does not split into equal shares
        whose ``envs * num_steps`` ``num_minibatches`` divides."""
        if isinstance(devices, bool) or not isinstance(devices, int) or devices < 1:
            raise ValueError(f"devices must be a positive integer, got {devices!r}")
        total = self.num_envs * devices if self.scaling == "weak" else self.num_envs
        if total % devices:
            raise ValueError(
                f"num_envs={total} does not split over {devices} devices (scaling: strong): "
                f"use a multiple of {devices}, fewer devices, or scaling: weak"
            )
        share = total // devices * self.num_steps
        if share % self.num_minibatches:
            raise ValueError(
                f"num_minibatches={self.num_minibatches} does not divide a device's "
                f"{total // devices} envs x {self.num_steps} steps ({share} samples) on "
                f"{devices} devices"
            )
        return dataclasses.replace(self, num_envs=total, scaling="strong")

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
