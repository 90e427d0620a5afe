"""Wall time to "solved" on CartPole: our PPO on CartPole-v0 vs Stable-Baselines3 PPO on
Gymnasium's CartPole-v1, same machine, one command.

Solved = the greedy policy's mean return over 20 fresh episodes >= 475 (Gymnasium's
threshold), checked after every chunk of training. Wall time counts everything from the
start of training (compilation included for ours, with the persistent compile cache off).
Evaluation time is excluded for both (its clock is paused).

    python benchmarks/training_speed.py --json training_speed_cpu2_cartpole

Stable-Baselines3 needs torch: ``pip install torch`` from a CPU wheel index first, then
``pip install 'jaxenvs[bench-sb3]'``; without it that line is reported skipped.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path
from typing import Any

import jax
import jax.numpy as jnp
import results_io
from sb3_zoo import zoo_cartpole_ppo

import jaxenvs
from jaxenvs.agents import base, ppo
from jaxenvs.bench import machine
from jaxenvs.config import apply_overrides, load_yaml
from jaxenvs.core import Env

THRESHOLD = 475.0
EVAL_EPISODES = 20

CONFIG_FILE = Path(jaxenvs.__file__).parent / "configs" / "ppo_CartPole-v0.yaml"


def our_config() -> ppo.PPOConfig:
    """The shipped PPO config of CartPole-v0 (what ``jaxenvs train CartPole-v0`` uses)."""
    agent = load_yaml(CONFIG_FILE)["agent"]
    return apply_overrides(ppo.PPOConfig(), agent, str(CONFIG_FILE))


def _greedy_returns(env: Env, trainer: base.Trainer) -> Any:
    """jitted ``(policy_params, key) -> returns`` of EVAL_EPISODES first episodes."""

    def one(pp: Any, key: jax.Array) -> jax.Array:
        state = env.reset(key)

        def body(carry: Any, _: None) -> tuple[Any, None]:
            s, ret, alive = carry
            s = env.step(s, trainer.act(pp, s.obs, key))
            ret = ret + jnp.where(alive, s.reward, 0.0)
            return (s, ret, alive & ~s.done), None

        init = (state, jnp.zeros(()), jnp.ones((), bool))
        (_, ret, _), _ = jax.lax.scan(body, init, None, length=env.episode_length)
        return ret

    return jax.jit(
        lambda pp, key: jax.vmap(one, in_axes=(None, 0))(pp, jax.random.split(key, EVAL_EPISODES))
    )


def run_ours(config: ppo.PPOConfig, seed: int) -> dict[str, Any]:
    env = jaxenvs.make("CartPole-v0")
    assert isinstance(env, Env)
    trainer = ppo.make_trainer(env, config)
    chunk = jax.jit(trainer.chunk)
    evaluate = _greedy_returns(env, trainer)
    key = jax.random.key(seed)
    train_key, eval_key = jax.random.split(key)
    wall = 0.0
    t0 = time.perf_counter()
    rs = jax.jit(trainer.init)(train_key)
    first_chunk = None
    for i in range(trainer.num_chunks):
        rs, metrics = chunk(rs)
        jax.block_until_ready(rs)
        wall += time.perf_counter() - t0
        first_chunk = first_chunk or wall
        rets = evaluate(trainer.policy_params(rs), jax.random.fold_in(eval_key, i))
        mean = float(rets.mean())
        steps = int(metrics["env_steps"])
        print(f"# ours: {steps} steps, {wall:.1f} s, greedy mean {mean:.1f}", flush=True)
        if mean >= THRESHOLD:
            return {
                "solved": True,
                "wall_s": wall,
                "env_steps": steps,
                "eval_mean": mean,
                "first_chunk_s": first_chunk,
            }
        t0 = time.perf_counter()
    return {"solved": False, "wall_s": wall, "env_steps": int(metrics["env_steps"])}


def run_sb3(seed: int, max_steps: int, check_every: int) -> dict[str, Any]:
    try:
        import gymnasium
        from stable_baselines3.common.callbacks import BaseCallback
        from stable_baselines3.common.evaluation import evaluate_policy
    except ImportError as err:
        return {"skipped": True, "reason": f"not installed: {err}"}

    class Solved(BaseCallback):
        """Evaluates every ``check_every`` steps with the clock paused; stops when solved."""

        def __init__(self) -> None:
            super().__init__()
            self.eval_env = gymnasium.make("CartPole-v1")
            self.eval_s = 0.0
            self.result: dict[str, Any] = {"solved": False}
            self.next_check = check_every

        def _on_step(self) -> bool:
            if self.num_timesteps < self.next_check:
                return True
            self.next_check += check_every
            t0 = time.perf_counter()
            mean, _ = evaluate_policy(
                self.model, self.eval_env, n_eval_episodes=EVAL_EPISODES, deterministic=True
            )
            self.eval_s += time.perf_counter() - t0
            print(f"# sb3: {self.num_timesteps} steps, greedy mean {mean:.1f}", flush=True)
            if mean >= THRESHOLD:
                self.result = {
                    "solved": True,
                    "env_steps": self.num_timesteps,
                    "eval_mean": float(mean),
                }
                return False
            return True

    t0 = time.perf_counter()
    model = zoo_cartpole_ppo(seed)
    cb = Solved()
    model.learn(total_timesteps=max_steps, callback=cb)
    wall = time.perf_counter() - t0 - cb.eval_s
    return {**cb.result, "wall_s": wall, "env_steps": cb.result.get("env_steps", max_steps)}


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=(__doc__ or "").splitlines()[0])
    parser.add_argument("--seeds", nargs="+", type=int, default=[0])
    parser.add_argument("--sb3-max-steps", type=int, default=300_000)
    parser.add_argument("--sb3-check-every", type=int, default=5_000)
    parser.add_argument("--json", default=None, help=results_io.HELP)
    args = parser.parse_args(argv)
    results = []
    for seed in args.seeds:
        results.append({"who": "jaxenvs PPO", "seed": seed, **run_ours(our_config(), seed)})
        results.append(
            {
                "who": "SB3 PPO",
                "seed": seed,
                **run_sb3(seed, args.sb3_max_steps, args.sb3_check_every),
            }
        )
    for r in results:
        print(json.dumps(r))
    if args.json:
        title = "wall time to solved CartPole: our PPO against Stable-Baselines3 PPO"
        extra = {"bench_machine": machine(), "config": str(our_config())}
        results_io.write(args.json, results_io.record(args.json, title, results, extra=extra))


if __name__ == "__main__":
    main()
