"""A public test battery for jaxenvs tasks: ours pass it, and so should yours.

Usage::

    from jaxenvs.testing import check_task
    check_task(jaxenvs.make("MyTask-v0"))      # raises TaskCheckError naming what failed

or, to run the checks one by one (e.g. as separate pytest tests sharing one compile)::

    checker = TaskChecker(env)
    checker.check_single_trace()
    ...
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from jaxenvs.actions import random_actions
from jaxenvs.core import STANDARD_INFO_KEYS, BatchedEnv, Env, State
from jaxenvs.core.xla import jit


class TaskCheckError(AssertionError):
    """A task failed one of the battery's checks."""


def _fail(name: str, message: str) -> None:
    raise TaskCheckError(f"[{name}] {message}")


def _counting_jit(fn: Callable[..., Any]) -> tuple[Callable[..., Any], list[int]]:
    count = [0]

    def traced(*args: Any) -> Any:
        count[0] += 1
        return fn(*args)

    return jit(traced), count


def _leaves_close(a: Any, b: Any, atol: float) -> bool:
    la, lb = jax.tree.leaves(a), jax.tree.leaves(b)
    if len(la) != len(lb):
        return False
    for x, y in zip(la, lb, strict=True):
        if jax.dtypes.issubdtype(x.dtype, jax.dtypes.prng_key):
            x, y = jax.random.key_data(x), jax.random.key_data(y)
        x, y = np.asarray(x), np.asarray(y)
        if x.dtype.kind in "fc":
            if not np.allclose(x, y, atol=atol, rtol=1e-4, equal_nan=True):
                return False
        elif x.dtype == y.dtype and x.dtype.kind in "biu" and not np.array_equal(x, y):
            return False
    return True


class TaskChecker:
    """Runs the battery against one env, compiling reset/step once and reusing them."""

    def __init__(self, env: Env, num_envs: int = 8, rollout_steps: int = 300) -> None:
        if isinstance(env, BatchedEnv):
            env = env.env
        self.env = env
        self.num_envs = num_envs
        self.rollout_steps = rollout_steps
        self.reset, self.reset_count = _counting_jit(env.reset)
        self.step, self.step_count = _counting_jit(env.step)
        self.benv = BatchedEnv(env, num_envs, devices=1)
        self._rollout = jit(self._rollout_fn)

    def _rollout_fn(self, key: jax.Array) -> tuple[State, State]:
        reset_key, run_key = jax.random.split(key)
        state0 = self.benv.reset(reset_key)

        def body(carry: tuple[State, jax.Array], _: None) -> tuple[Any, State]:
            state, k = carry
            k, ak = jax.random.split(k)
            state = self.benv.step(state, random_actions(self.env, ak, (self.num_envs,)))
            return (state, k), state

        _, traj = jax.lax.scan(body, (state0, run_key), None, length=self.rollout_steps)
        return state0, traj

    def check_single_trace(self) -> None:
        """reset and step each trace exactly once across repeated calls."""
        s = self.reset(jax.random.key(0))
        s = self.reset(jax.random.key(1))
        for i in range(3):
            s = self.step(s, random_actions(self.env, jax.random.key(10 + i)))
        jax.block_until_ready(s)
        if self.reset_count[0] != 1 or self.step_count[0] != 1:
            _fail(
                "single_trace",
                f"reset traced {self.reset_count[0]}x and step {self.step_count[0]}x "
                "(expected once each): something in them depends on Python values",
            )

    def check_determinism(self) -> None:
        """Same key gives the same state; different keys give different states."""
        a = self.reset(jax.random.key(3))
        b = self.reset(jax.random.key(3))
        c = self.reset(jax.random.key(4))
        if not _leaves_close(a, b, atol=0.0):
            _fail("determinism", "reset with the same key gave different states")
        if np.allclose(np.asarray(a.obs), np.asarray(c.obs)):
            _fail("determinism", "reset with different keys gave the same observation")
        act = random_actions(self.env, jax.random.key(5))
        if not _leaves_close(self.step(a, act), self.step(b, act), atol=0.0):
            _fail("determinism", "step from equal states with the same action differed")

    def check_keys(self) -> None:
        """Hooks draw only from the keys ``step`` hands them.

        A step is deterministic per state key and advances the key (the next key differs
        from the one before and across different keys). If ``_observe`` or ``_act``
        depends on its key (observation noise, action delay, pushes), a step from the same
        state under a different key must give a different observation or physics state,
        and the same key must give the same one.
        """
        env, params = self.env, self.env.default_params
        s = self.reset(jax.random.key(11))
        other = s.replace(key=jax.random.key(13))
        act = random_actions(env, jax.random.key(12))
        a, a2, b = self.step(s, act), self.step(s, act), self.step(other, act)
        if not _leaves_close(a, a2, atol=0.0):
            _fail("keys", "step from equal states with the same key differed")
        keys = [np.asarray(jax.random.key_data(x.key)) for x in (s, a, other, b)]
        if np.array_equal(keys[0], keys[1]) or np.array_equal(keys[1], keys[3]):
            _fail("keys", "step did not advance state.key (it must split it, never reuse it)")
        k1, k2 = jax.random.key(21), jax.random.key(22)

        def observe(k: jax.Array) -> jax.Array:
            return env._observe(k, s.data, s.extras, params)

        def act_qpos(k: jax.Array) -> jax.Array:
            return env._act(k, s.data, s.extras, act, params)[0].qpos

        for hook, fn, got in (("_observe", observe, "obs"), ("_act", act_qpos, "qpos")):
            run = jit(fn)
            first, again, second = (np.asarray(run(k)) for k in (k1, k1, k2))
            if not np.array_equal(first, again, equal_nan=True):
                _fail("keys", f"{hook} gave different results for the same key")
            if np.allclose(first, second):
                continue  # the hook does not draw from its key
            out_a = a.obs if got == "obs" else a.data.qpos
            out_b = b.obs if got == "obs" else b.data.qpos
            if np.allclose(np.asarray(out_a), np.asarray(out_b)):
                _fail(
                    "keys",
                    f"{hook} draws from its key, but steps under different state keys gave "
                    f"the same {got}: step does not hand it a key drawn from state.key",
                )

    def check_spaces(self) -> None:
        """Observations and actions conform to the declared spaces; info keys are fixed."""
        env = self.env
        s = self.reset(jax.random.key(6))
        obs = np.asarray(s.obs)
        if obs.shape != (env.observation_size,) or obs.dtype != np.float32:
            _fail(
                "spaces",
                f"obs has shape {obs.shape} dtype {obs.dtype}, expected "
                f"({env.observation_size},) float32",
            )
        if not env.observation_space.contains(obs):
            _fail("spaces", f"reset obs {obs} not in {env.observation_space}")
        sample = env.action_space.sample()
        s2 = self.step(s, jnp.asarray(sample))
        if set(s.info) != set(s2.info):
            _fail("spaces", f"info keys changed: {sorted(s.info)} -> {sorted(s2.info)}")
        missing = set(STANDARD_INFO_KEYS) - set(s2.info)
        if missing:
            _fail("spaces", f"info lacks standard keys {sorted(missing)}")
        if np.asarray(s2.reward).shape != () or np.asarray(s2.terminated).dtype != bool:
            _fail("spaces", "reward must be a scalar and terminated a bool")

    def check_vmap_matches(self, n: int = 4, atol: float = 1e-5) -> None:
        """``vmap(step)`` over a batch equals stacked single-env steps.

        A task whose step amplifies rounding (e.g. an unconverged contact solve, where
        the batched program's different reduction order changes a few last bits) may
        declare a looser ``vmap_atol`` class attribute; a real batching bug is O(1).
        """
        atol = max(atol, float(getattr(self.env, "vmap_atol", 0.0)))
        keys = jax.random.split(jax.random.key(7), n)
        states = [self.reset(k) for k in keys]
        acts = [random_actions(self.env, k) for k in jax.random.split(jax.random.key(8), n)]
        singles = [self.step(s, a) for s, a in zip(states, acts, strict=True)]
        stacked_in = jax.tree.map(lambda *xs: jnp.stack(xs), *states)
        batched = jit(jax.vmap(self.env.step))(stacked_in, jnp.stack(acts))
        stacked_out = jax.tree.map(lambda *xs: jnp.stack(xs), *singles)
        if not _leaves_close(
            (batched.obs, batched.reward, batched.data.qpos),
            (stacked_out.obs, stacked_out.reward, stacked_out.data.qpos),
            atol,
        ):
            _fail("vmap", "vmap(step) differs from stacked single steps")

    def rollout(self, seed: int = 9) -> tuple[State, State]:
        """A batched random-action rollout: (initial state, trajectory of states)."""
        return jax.block_until_ready(self._rollout(jax.random.key(seed)))

    def check_rollout(self, seed: int = 9) -> None:
        """Long random rollouts stay finite, inside the spaces, and auto-reset freshly."""
        state0, traj = self.rollout(seed)
        obs, rew = np.asarray(traj.obs), np.asarray(traj.reward)
        if not np.all(np.isfinite(obs)) or not np.all(np.isfinite(rew)):
            _fail("rollout", "non-finite observation or reward in a random rollout")
        if np.asarray(traj.info["diverged"]).any():
            _fail("rollout", "physics diverged under random actions")
        done = np.asarray(traj.terminated | traj.truncated)
        if done.any():
            time = np.asarray(traj.time)
            if not np.all(time[done] == 0):
                _fail("rollout", "a finished env was not reset (time != 0)")
            starts = obs[done]
            if len(starts) > 1 and np.allclose(starts, starts[0]):
                _fail("rollout", "auto-reset returned the same start every time (cached)")
            final = np.asarray(traj.info["final_obs"])[done]
            if np.allclose(final, starts):
                _fail("rollout", "info['final_obs'] does not keep the finished episode's obs")
        both = np.asarray(traj.terminated & traj.truncated)
        if both.any():
            _fail("rollout", "terminated and truncated both set on one transition")

    def run_all(self) -> None:
        self.check_single_trace()
        self.check_determinism()
        self.check_keys()
        self.check_spaces()
        self.check_vmap_matches()
        self.check_rollout()


def check_task(env: Env, num_envs: int = 8, rollout_steps: int = 300) -> None:
    """Run the whole battery on ``env``; raises :class:`TaskCheckError` on the first
    failure with a message naming the check and what went wrong."""
    TaskChecker(env, num_envs=num_envs, rollout_steps=rollout_steps).run_all()


def check_engine_parity(
    env_id: str,
    steps: int = 30,
    atol: float = 1e-4,
    seed: int = 0,
    action_scale: float = 1.0,
    **overrides: Any,
) -> None:
    """Step ``env_id`` under MJX and under MuJoCo's C engine (``physics="c"``) from the
    same reset with the same random actions; the observation, reward, termination and
    every task metric must agree within ``atol`` (and a relative 1e-4) after every step.
    Continuous random actions are scaled by ``action_scale``.

    The C engine writes only the derived fields the task declares in ``derived_fields``
    (:mod:`jaxenvs.physics.cengine`); a task that reads another one fails here with the
    engine's :class:`~jaxenvs.physics.cengine.CEngineError` naming the field and
    ``derived_fields``, when its program is traced. A difference in the values raises
    :class:`TaskCheckError`.
    """
    from jaxenvs import registry

    runs = {}
    for physics in ("mjx", "c"):
        env = registry.make(env_id, physics=physics, **overrides)
        assert isinstance(env, Env)

        def roll(key: jax.Array, env: Env = env) -> Any:
            reset_key, act_key = jax.random.split(key)

            def body(s: State, k: jax.Array) -> tuple[State, Any]:
                action = random_actions(env, k)
                if not env.discrete:
                    action = action * action_scale
                s = env.step(s, action)
                metrics = {m: s.info[m] for m in env.metric_keys}
                return s, {"obs": s.obs, "reward": s.reward, "terminated": s.terminated, **metrics}

            keys = jax.random.split(act_key, steps)
            return jax.lax.scan(body, env.reset(reset_key), keys)[1]

        runs[physics] = jax.device_get(jit(roll)(jax.random.key(seed)))
    for name, want in runs["mjx"].items():
        got, want = np.asarray(runs["c"][name], np.float64), np.asarray(want, np.float64)
        close = np.isclose(got, want, atol=atol, rtol=1e-4)
        if not close.all():
            step = int(np.argwhere(~close)[0][0])
            nan = " (NaN under physics='c')" if np.isnan(got).any() else ""
            _fail(
                "engine_parity",
                f"{env_id}: {name} differs at step {step}: max |mjx - c| = "
                f"{np.nanmax(np.abs(got - want)):.3g}{nan}",
            )
