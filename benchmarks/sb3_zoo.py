"""Stable-Baselines3's PPO on Gymnasium's CartPole-v1 with RL Baselines3 Zoo's tuned
hyperparameters (or SB3's own defaults): the training-speed peer of ``training_speed.py``
and ``main_command.py``.

Imports only SB3 (and what it needs), so a process timing SB3 pays for nothing else."""

from __future__ import annotations

from typing import Any


def zoo_cartpole_ppo(seed: int) -> Any:
    """A fresh ``stable_baselines3.PPO`` on 8 CartPole-v1 envs, the Zoo's settings, on the CPU."""
    from stable_baselines3 import PPO
    from stable_baselines3.common.env_util import make_vec_env

    venv = make_vec_env("CartPole-v1", n_envs=8, seed=seed)
    return PPO(
        "MlpPolicy",
        venv,
        n_steps=32,
        batch_size=256,
        gae_lambda=0.8,
        gamma=0.98,
        n_epochs=20,
        ent_coef=0.0,
        learning_rate=lambda f: 1e-3 * f,
        clip_range=lambda f: 0.2 * f,
        seed=seed,
        device="cpu",
        verbose=0,
    )


def default_cartpole_ppo(seed: int) -> Any:
    """A fresh ``stable_baselines3.PPO`` on one CartPole-v1 env with SB3's own defaults (what
    ``PPO("MlpPolicy", "CartPole-v1")`` trains with: n_steps 2048, batch 64, 10 epochs,
    learning rate 3e-4), on the CPU."""
    from stable_baselines3 import PPO

    return PPO("MlpPolicy", "CartPole-v1", seed=seed, device="cpu", verbose=0)
