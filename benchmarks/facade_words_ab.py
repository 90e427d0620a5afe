"""A/B: the Gymnasium facade's state as words buffers (jaxenvs/compat/gymnasium/words.py)
against a plain jit over State whose step also returns the obs, reward, flags and info of
the step packed in one float32 array (the one host read); the same process, the two
alternating round by round, medians of the rounds.

    python benchmarks/facade_words_ab.py CartPole-v0,Reacher-v0 16,256,1024 5 single
"""

from __future__ import annotations

import statistics
import sys
from typing import Any

import gymnasium as gym
import jax
import jax.numpy as jnp
import numpy as np
from facade import time_single, time_vector

import jaxenvs  # noqa: F401
from jaxenvs.compat.gymnasium import JaxEnv, JaxVectorEnv, checks, programs, vector
from jaxenvs.core.xla import jit


def _report(s: Any, keys: tuple[str, ...], batched: bool) -> jax.Array:
    def col(x: jax.Array) -> jax.Array:
        x = x.astype(jnp.float32)
        return x[..., None] if batched else x[None]

    cols = [col(s.reward), col(s.terminated), col(s.truncated)]
    return jnp.concatenate([s.obs, *cols, *[col(s.info[k]) for k in keys]], axis=-1)


def _kinds(env: Any, keys: tuple[str, ...]) -> list[str]:
    example = jax.eval_shape(lambda: env.reset(jax.random.key(0)))
    return [np.dtype(example.info[k].dtype).kind for k in keys]


def _value(column: Any, kind: str) -> Any:
    if kind == "f":
        return column.astype(np.float64)
    return column != 0 if kind == "b" else column.astype(np.int64)


class PlainVec(JaxVectorEnv):
    """The vector env, NEXT_STEP, its State a pytree of device arrays."""

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        task, env = self._fns.batched, self.jax_env
        advance = programs._advance(task, self.autoreset_mode)
        keys = programs.info_keys(env)
        self._keys, self._kinds, self._n = keys, _kinds(env, keys), env.observation_size

        def step(state: Any, action: Any) -> Any:
            s = advance(state, action)
            return s, _report(s, keys, True)

        def reset(seed: Any) -> Any:
            s = task.reset(jax.random.key(seed))
            return s, _report(s, keys, True)

        self._pstep, self._preset = jit(step, donate_argnums=0), jit(reset)

    def reset(self, *, seed: Any = None, options: Any = None) -> Any:
        gym.vector.VectorEnv.reset(self, seed=seed)
        self._state, rep = self._preset(checks.seed32(self.np_random))
        self._ended[:] = False
        return np.asarray(rep)[:, : self._n].copy(), {}

    def step(self, actions: Any) -> Any:
        actions = checks.check_action(self.jax_env, actions, self.num_envs)
        self._state, rep = self._pstep(self._state, actions)
        rep, n = np.asarray(rep), self._n
        term, trunc = rep[:, n + 1] != 0, rep[:, n + 2] != 0
        out = {
            k: _value(rep[:, n + 3 + j], kind)
            for j, (k, kind) in enumerate(zip(self._keys, self._kinds, strict=True))
        }
        infos = vector._infos(out, ~self._ended)
        self._ended = term | trunc
        return rep[:, :n].copy(), rep[:, n].astype(np.float64), term, trunc, infos


class PlainSingle(JaxEnv):
    """The one env, its State a pytree of device arrays."""

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        env = self.jax_env
        keys = programs.info_keys(env)
        self._kind = list(zip(keys, _kinds(env, keys), strict=True))
        self._n = env.observation_size

        def step(state: Any, action: Any) -> Any:
            s = env.step(state, action)
            return s, _report(s, keys, False)

        def reset(seed: Any) -> Any:
            s = env.reset(jax.random.key(seed))
            return s, _report(s, keys, False)

        self._pstep, self._preset = jit(step, donate_argnums=0), jit(reset)

    def reset(self, *, seed: Any = None, options: Any = None) -> Any:
        gym.Env.reset(self, seed=seed)
        self._state, rep = self._preset(checks.seed32(self.np_random))
        self._bufs = ()
        return np.asarray(rep)[: self._n].copy(), {}

    def step(self, action: Any) -> Any:
        if not (type(action) is np.ndarray and action.dtype == np.float32):
            action = checks.check_action(self.jax_env, action)
        self._state, rep = self._pstep(self._state, action)
        rep, n = np.asarray(rep), self._n
        vals = rep[n:].tolist()
        info = {
            k: v if kind == "f" else v != 0.0 if kind == "b" else int(v)
            for (k, kind), v in zip(self._kind, vals[3:], strict=True)
        }
        return rep[:n].copy(), vals[0], vals[1] != 0.0, vals[2] != 0.0, info


def _ab(name: str, words: Any, plain: Any, timer: Any, rounds: int) -> None:
    res: dict[str, list[float]] = {"words": [], "plain": []}
    for _ in range(rounds):
        res["words"].append(timer(words))
        res["plain"].append(timer(plain))
    w, p = statistics.median(res["words"]), statistics.median(res["plain"])
    every = {k: [round(x) for x in v] for k, v in res.items()}
    print(f"{name}: words {w:,.0f} plain {p:,.0f} steps/s, ratio {w / p:.2f}  {every}", flush=True)


def main() -> None:
    tasks, sizes = sys.argv[1].split(","), [int(x) for x in sys.argv[2].split(",")]
    rounds, single = int(sys.argv[3]), sys.argv[4:] == ["single"]
    for task in tasks:
        if single:
            pair = JaxEnv(task), PlainSingle(task)
            for env in pair:
                time_single(env, 50)
            _ab(f"{task} one env", *pair, lambda e: time_single(e, 3000), rounds)
        for n in sizes:
            pair = JaxVectorEnv(task, n), PlainVec(task, n)
            for env in pair:
                time_vector(env, 3)
            steps = max(20, 60000 // n)
            _ab(f"{task} x{n}", *pair, lambda e, s=steps: time_vector(e, s), rounds)


if __name__ == "__main__":
    main()
