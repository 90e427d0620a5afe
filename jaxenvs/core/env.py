"""The env state, the task config base and the :class:`Env` base class (see
:mod:`jaxenvs.core` for the task hooks, keys and ``info`` contract)."""

from __future__ import annotations

import abc
import dataclasses
from typing import TYPE_CHECKING, Any, Generic, TypeVar

import gymnasium
import jax
import jax.numpy as jnp
import numpy as np
from flax import struct

from jaxenvs.config import require
from jaxenvs.physics import PHYSICS_CHOICES, EngineFigures, resolve_engine
from jaxenvs.physics.sim import Sim

if TYPE_CHECKING:
    from mujoco import mjx

PyTree = Any
Params = Any


#: folded into a reset's key for the carry's draw (:meth:`Env.initial_carry`), so that
#: the reset's other keys are those of ``split(key, 3)``
CARRY_SALT = 0x63617279

STANDARD_INFO_KEYS = (
    "episode_return",
    "episode_length",
    "final_obs",
    "final_return",
    "final_length",
    "nan_actions",
    "diverged",
)


def check_key(key: Any, where: str) -> None:
    """TypeError/ValueError (at trace time) unless ``key`` is ONE PRNG key: a typed key
    of shape ``()`` or a raw ``uint32`` key (one axis)."""
    dtype, shape = getattr(key, "dtype", None), getattr(key, "shape", None)
    typed = dtype is not None and jax.dtypes.issubdtype(dtype, jax.dtypes.prng_key)
    if not typed and (dtype != np.uint32 or not shape):
        got = type(key).__name__ + ("" if dtype is None else f" of {dtype}{list(shape or ())}")
        raise TypeError(f"{where}: expected a PRNG key (jax.random.key(seed)), got {got}")
    if (typed and shape != ()) or (not typed and len(shape or ()) != 1):
        raise ValueError(
            f"{where}: expected one PRNG key, got a key array of shape {shape}; a batch of "
            "keys goes to jax.vmap or a BatchedEnv"
        )


def check_state(state: Any, batch: tuple[int, ...], where: str) -> None:
    """TypeError/ValueError (at trace time) unless ``state`` is a :class:`State` of
    ``batch`` envs (``()``: one env)."""
    if not isinstance(state, State):
        raise TypeError(f"{where}: expected a State, got {type(state).__name__}")
    shape = tuple(jnp.shape(state.time))
    if shape != batch:
        one = "one env's state" if not batch else f"a state of {batch[0]} envs"
        got = f"a batch of {shape[0]} envs" if shape else "one env's state"
        raise ValueError(f"{where}: expected {one}, got {got} (state.time has shape {shape})")


class NoExtras(struct.PyTreeNode):
    """The ``extras`` of a task that keeps no state of its own (no leaves)."""


class State(struct.PyTreeNode):
    """The full state of one env (or of a batch, with a leading axis on every leaf).

    Attributes:
      data: the MJX physics state.
      obs: observation, float32 of shape ``(observation_size,)``.
      reward: float32 scalar reward of the last transition (0 after reset).
      terminated: the last transition reached a terminal state (no bootstrap).
      truncated: the episode hit its time limit (bootstrap from ``info["final_obs"]``).
      info: fixed dict of arrays, see the module docstring.
      extras: the task's own state (targets, commanded velocities, ...): a frozen
        pytree of fixed structure per task, :class:`NoExtras` where there is none.
      time: int32 steps taken in the current episode.
      key: the PRNG key that drives this env's future randomness.
      params: per-env params of a randomised batched env, else ``None``.
      carry: the task's per-env state that survives auto-resets (a curriculum level,
        a counter of finished episodes): made by the task's ``_carry_init`` at
        :meth:`Env.reset`, updated by its ``_carry_update`` from each finished episode
        before the next start, read by its ``_start``; :class:`NoExtras` (no leaves)
        for a task that keeps none.
    """

    data: mjx.Data
    obs: jax.Array
    reward: jax.Array
    terminated: jax.Array
    truncated: jax.Array
    info: dict[str, jax.Array]
    extras: PyTree
    time: jax.Array
    key: jax.Array
    params: Params = None
    carry: PyTree = None

    @property
    def done(self) -> jax.Array:
        """``terminated | truncated``."""
        return jnp.logical_or(self.terminated, self.truncated)


@dataclasses.dataclass(frozen=True)
class TaskConfig:
    """Fields every task config has. Subclasses add their own.

    Attributes:
      episode_length: steps before truncation.
      divergence_bound: an env whose |qpos| or |qvel| exceeds this (or is non-finite) is
        terminated with ``info["diverged"]``.
      physics: the engine that steps the physics: ``"mjx"`` (MJX, any JAX backend),
        ``"c"`` (MuJoCo's C engine, CPU only, :mod:`jaxenvs.physics.cengine`) or ``"auto"`` (MJX on
        an accelerator; on a CPU the task's measured faster engine at the batch size,
        :func:`jaxenvs.physics.resolve_engine`). A built env's config holds the resolved
        engine.
    """

    episode_length: int = 1000
    divergence_bound: float = 1e4
    physics: str = "auto"

    def validate(self) -> None:
        require(self.episode_length > 0, "episode_length", "must be positive")
        require(
            self.physics in PHYSICS_CHOICES,
            "physics",
            f"must be one of {', '.join(PHYSICS_CHOICES)}",
        )
        for name in ("timestep", "substeps"):
            if hasattr(self, name):
                require(getattr(self, name) > 0, name, "must be positive")
        require(self.divergence_bound > 0, "divergence_bound", "must be positive")


ConfigT = TypeVar("ConfigT", bound=TaskConfig)


class Env(abc.ABC, Generic[ConfigT]):
    """Base class of every jaxenvs task. Holds no mutable state after construction."""

    #: tuple of task-specific info keys, fixed per task.
    metric_keys: tuple[str, ...] = ()

    #: how many env steps a rollout ``lax.scan`` should unroll (``scan(..., unroll=...)``):
    #: a per-task speed/compile-time trade-off, forced to 1 under the C engine. The
    #: library's own rollouts (benchmarks, sharded rollouts) use it; pass it to your own
    #: scans the same way.
    scan_unroll: int = 1

    #: how the task is best stepped on a CPU, for a task outside the built-in table
    #: (:mod:`jaxenvs.physics.figures`); ``None``: the table's row, or MJX everywhere
    engine_figures: EngineFigures | None = None

    #: the derived ``mjx.Data`` fields the task reads (``sensordata``, ``actuator_force``,
    #: ``site_xpos``, ...; the state ``qpos``, ``qvel``, ... and the inputs such as
    #: ``mocap_pos`` are always there). Under ``physics="c"`` the engine writes only these,
    #: and a state holds :class:`jaxenvs.physics.cengine.Unavailable` for the others, which
    #: raises naming this attribute when read. ``None``: every field (a task that does not
    #: say). MJX computes every field whatever this says.
    derived_fields: tuple[str, ...] | None = None

    def __init__(self, config: ConfigT, sim: Sim) -> None:
        requested = getattr(config, "physics", "auto")
        physics = resolve_engine(type(self), requested)
        if requested != physics:
            config = dataclasses.replace(config, physics=physics)
        self.config = config
        #: the engine stepping this env: ``"mjx"`` or ``"c"``
        self.physics = physics
        self.sim = (
            sim if physics == "mjx" else sim.with_physics(physics, derived=self.derived_fields)
        )
        if physics == "c":
            # unrolling lets XLA fuse across MJX steps; a C step is a host call that
            # cannot fuse, so unrolled copies would only add compile time
            self.scan_unroll = 1

    # ----------------------------------------------------------------- description
    @property
    @abc.abstractmethod
    def observation_size(self) -> int: ...

    @property
    @abc.abstractmethod
    def action_size(self) -> int:
        """Number of actuators, or number of actions for discrete tasks."""

    @property
    def discrete(self) -> bool:
        """True if actions are integers in ``[0, action_size)``."""
        return False

    @property
    def observation_space(self) -> gymnasium.spaces.Box:
        return gymnasium.spaces.Box(-np.inf, np.inf, (self.observation_size,), np.float32)

    @property
    def action_space(self) -> gymnasium.spaces.Space:
        if self.discrete:
            return gymnasium.spaces.Discrete(self.action_size)
        return gymnasium.spaces.Box(-1.0, 1.0, (self.action_size,), np.float32)

    @property
    def action_shape(self) -> tuple[int, ...]:
        return () if self.discrete else (self.action_size,)

    @property
    def episode_length(self) -> int:
        return self.config.episode_length

    @property
    def control_dt(self) -> float:
        return self.sim.control_dt

    @property
    @abc.abstractmethod
    def default_params(self) -> Params: ...

    def sample_params(self, key: jax.Array) -> Params:
        """Draw randomised params (domain randomisation); default: no randomisation."""
        del key
        return self.default_params

    # ----------------------------------------------------------------- task hooks
    def _init(self, key: jax.Array, params: Params) -> tuple[mjx.Data, PyTree]:
        """The initial physics state and ``extras``, drawn from ``key``. A task that keeps
        a carry overrides :meth:`_start` instead."""
        raise NotImplementedError(
            f"{type(self).__name__} defines neither _init(key, params) nor "
            "_start(key, params, carry)"
        )

    def _start(self, key: jax.Array, params: Params, carry: PyTree) -> tuple[mjx.Data, PyTree]:
        """The initial physics state and ``extras`` of an episode started with the env's
        ``carry``; default: :meth:`_init` (the carry is not read)."""
        del carry
        return self._init(key, params)

    def _carry_init(self, key: jax.Array, params: Params) -> PyTree:
        """The carry an env starts with at :meth:`reset` (``key``: its own draw, apart from
        the reset's other keys); default: :class:`NoExtras`, no carry."""
        del key, params
        return NoExtras()

    def _carry_update(self, carry: PyTree, final: State, params: Params) -> PyTree:
        """The carry the next episode starts with, from the finished episode's last state
        ``final`` (its ``data``, ``extras``, ``info`` and ``time``; ``carry`` is
        ``final.carry``). Called by an auto-reset (:class:`~jaxenvs.core.BatchedEnv`, the
        Gymnasium and gymnax adapters) for the envs that finished, before their fresh
        start; default: unchanged."""
        del final, params
        return carry

    @abc.abstractmethod
    def _act(
        self, key: jax.Array, data: mjx.Data, extras: PyTree, action: jax.Array, params: Params
    ) -> tuple[mjx.Data, PyTree]:
        """Apply the sanitised ``action`` for one control step; returns the new physics
        state and ``extras`` (same structure and dtypes). ``key``: this step's act key."""

    @abc.abstractmethod
    def _observe(self, key: jax.Array, data: mjx.Data, extras: PyTree, params: Params) -> jax.Array:
        """The observation, shape ``(observation_size,)``. ``key``: this step's (or
        reset's) observation key."""

    @abc.abstractmethod
    def _reward(
        self,
        prev: mjx.Data,
        data: mjx.Data,
        action: jax.Array,
        extras: PyTree,
        params: Params,
    ) -> tuple[jax.Array, dict[str, jax.Array]]:
        """The reward of the transition ``prev -> data`` under ``action`` and the task's
        metrics (a dict with exactly the keys :attr:`metric_keys`)."""

    def _terminated(self, data: mjx.Data, extras: PyTree, params: Params) -> jax.Array:
        """True if ``data`` is a terminal state (no bootstrap). Default: never."""
        del data, extras, params
        return jnp.zeros((), bool)

    def _zero_metrics(self) -> dict[str, jax.Array]:
        return {k: jnp.zeros((), jnp.float32) for k in self.metric_keys}

    # ----------------------------------------------------------------- public API
    def reset(self, key: jax.Array, params: Params = None) -> State:
        """Start an episode from the task's initial-state distribution, with a new carry
        (:meth:`_carry_init`)."""
        check_key(key, f"{type(self).__name__}.reset")
        return self._reset_from(jax.random.split(key, 3), params, self.initial_carry(key, params))

    def reset_carried(self, key: jax.Array, params: Params, carry: PyTree) -> State:
        """An episode started from ``key`` as :meth:`reset` starts it, but with the env's
        ``carry`` kept (what an auto-reset does for one env: pass
        :meth:`next_carry` of the finished episode's last state)."""
        check_key(key, f"{type(self).__name__}.reset_carried")
        params = self.default_params if params is None else params
        return self._reset_from(jax.random.split(key, 3), params, carry)

    def initial_carry(self, key: jax.Array, params: Params = None) -> PyTree:
        """The carry :meth:`reset` with ``key`` starts the env with."""
        params = self.default_params if params is None else params
        return self._carry_init(jax.random.fold_in(key, CARRY_SALT), params)

    def next_carry(self, final: State, params: Params = None) -> PyTree:
        """The carry the episode after ``final`` (a finished episode's last state of one
        env) starts with: :meth:`_carry_update`'s."""
        if params is None:
            params = self.default_params if final.params is None else final.params
        return self._carry_update(final.carry, final, params)

    def _reset_from(self, keys: jax.Array, params: Params, carry: PyTree) -> State:
        """:meth:`reset` from ``keys``, the first 3 (at least) of ``jax.random.split(key,
        n)``: the state's next key, the init's and the observation's, and the env's
        ``carry``. A caller that needs more keys of the same ``key`` splits once (``n`` >
        3) and passes them all: with JAX's partitionable threefry the first 3 equal
        ``split(key, 3)``, so the state is :meth:`reset`'s, and it costs one PRNG call (a
        loop XLA compiles on a CPU) less."""
        params = self.default_params if params is None else params
        key, init_key, obs_key = keys[0], keys[1], keys[2]
        data, extras = self._start(init_key, params, carry)
        obs = self._observe(obs_key, data, extras, params).astype(jnp.float32)
        zero = jnp.zeros((), jnp.float32)
        info = {
            "episode_return": zero,
            "episode_length": jnp.zeros((), jnp.int32),
            "final_obs": obs,
            "final_return": zero,
            "final_length": jnp.zeros((), jnp.int32),
            "nan_actions": jnp.zeros((), jnp.int32),
            "diverged": jnp.zeros((), bool),
            **self._zero_metrics(),
        }
        return State(
            data=data,
            obs=obs,
            reward=zero,
            terminated=jnp.zeros((), bool),
            truncated=jnp.zeros((), bool),
            info=info,
            extras=extras,
            time=jnp.zeros((), jnp.int32),
            key=key,
            carry=carry,
        )

    def step(self, state: State, action: jax.Array, params: Params = None) -> State:
        """Advance one control step.

        ``params=None`` uses the params the batched env stored in ``state.params``, else
        ``default_params``. The action is validated at trace time (shape and dtype) and
        sanitised on device: NaN/inf entries become 0 (counted in ``info["nan_actions"]``),
        continuous actions are clipped to [-1, 1], discrete ones into range.
        """
        check_state(state, (), f"{type(self).__name__}.step")
        if params is None:
            params = self.default_params if state.params is None else state.params
        action, nan_count = self.sanitize_action(action)
        key, act_key, obs_key = jax.random.split(state.key, 3)
        data, extras = self._act(act_key, state.data, state.extras, action, params)
        out = self._reward(state.data, data, action, extras, params)
        if not (isinstance(out, tuple) and len(out) == 2):
            raise TypeError(
                f"{type(self).__name__}._reward must return (reward, metrics); termination "
                "is its own hook, _terminated(data, extras, params)"
            )
        reward, metrics = out
        terminated = jnp.asarray(self._terminated(data, extras, params), bool)
        obs = self._observe(obs_key, data, extras, params).astype(jnp.float32)

        bound = self.config.divergence_bound
        phys = jnp.concatenate([data.qpos, data.qvel])
        diverged = ~jnp.all(jnp.isfinite(phys)) | jnp.any(jnp.abs(phys) > bound)
        diverged = diverged | ~jnp.all(jnp.isfinite(obs)) | ~jnp.isfinite(reward)
        obs = jnp.where(diverged, jnp.nan_to_num(obs, posinf=bound, neginf=-bound), obs)
        obs = jnp.clip(obs, -bound, bound)
        reward = jnp.where(diverged, 0.0, reward).astype(jnp.float32)
        terminated = jnp.logical_or(terminated, diverged)

        time = state.time + 1
        truncated = jnp.logical_and(time >= self.config.episode_length, ~terminated)
        ep_return = state.info["episode_return"] + reward
        info = {
            "episode_return": ep_return,
            "episode_length": time,
            "final_obs": obs,
            "final_return": ep_return,
            "final_length": time,
            "nan_actions": nan_count,
            "diverged": diverged,
            **{k: jnp.asarray(v, jnp.float32) for k, v in metrics.items()},
        }
        return state.replace(
            data=data,
            obs=obs,
            reward=reward,
            terminated=terminated,
            truncated=truncated,
            info=info,
            extras=extras,
            time=time,
            key=key,
        )

    def sanitize_action(self, action: Any) -> tuple[jax.Array, jax.Array]:
        """Validate shape/dtype (trace time) and clean values (device)."""
        action = jnp.asarray(action)
        if action.shape != self.action_shape:
            raise ValueError(
                f"{type(self).__name__}: expected an action of shape {self.action_shape} "
                f"({self.action_space}), got shape {action.shape}"
            )
        if self.discrete:
            if not jnp.issubdtype(action.dtype, jnp.integer):
                raise TypeError(
                    f"{type(self).__name__}: expected an integer action for "
                    f"{self.action_space}, got dtype {action.dtype}"
                )
            return jnp.clip(action, 0, self.action_size - 1).astype(jnp.int32), jnp.zeros(
                (), jnp.int32
            )
        if not jnp.issubdtype(action.dtype, jnp.floating):
            raise TypeError(
                f"{type(self).__name__}: expected a floating-point action for "
                f"{self.action_space}, got dtype {action.dtype}"
            )
        action = action.astype(jnp.float32)
        bad = ~jnp.isfinite(action)
        action = jnp.clip(jnp.where(bad, 0.0, action), -1.0, 1.0)
        return action, jnp.any(bad).astype(jnp.int32)

    def __repr__(self) -> str:
        return f"{type(self).__name__}({self.config})"
