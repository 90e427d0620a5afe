"""The batched env: ``num_envs`` copies of an :class:`~jaxenvs.core.env.Env` stepped by one
vmapped function, with fresh random auto-resets."""

from __future__ import annotations

import dataclasses
import functools
from collections.abc import Callable
from typing import Any

import jax
import jax.numpy as jnp

from jaxenvs.core import placement
from jaxenvs.core.env import Env, Params, State, check_key, check_state
from jaxenvs.core.plan import Plan
from jaxenvs.core.plan import plan as make_plan


class BatchedEnv:
    """``num_envs`` copies of an :class:`Env` stepped by one vmapped function.

    Finished envs (terminated or truncated) come back already reset to a FRESH random
    initial state drawn with that env's own key; the finished episode's last observation,
    return and length stay in ``info["final_obs"]``, ``info["final_return"]`` and
    ``info["final_length"]``, and ``reward``/``terminated``/``truncated`` and the task's
    metrics in ``info`` still describe the transition that ended it. With
    ``randomize=True`` each env draws its own params from ``env.sample_params`` at every
    reset (domain randomisation): its state is
    ``env.reset(k, params)``'s for its key ``k``, the params drawn from
    ``jax.random.split(k, 4)[3]`` (with JAX's default partitionable threefry).

    **The plan.** How the batch runs is decided once, when it is made
    (:func:`jaxenvs.core.plan.plan`, kept as :attr:`plan`): the devices its env axis is
    split over (:func:`jaxenvs.core.placement.batch_devices`; ``devices=1`` keeps it on
    one) and how its auto-reset computes fresh starts. Over several devices a step runs
    as a program per device (:func:`jaxenvs.core.placement.per_device`) on every backend:
    each device steps its slice and resets its own finished envs, with no cross-device
    reduction. Within a device the reset is ``"compact"`` (on a CPU from 64 envs a device:
    fresh starts for the finished envs alone, in chunks of an eighth of the device's envs,
    a loop as long as the device's own count needs) or ``"whole"`` (fresh starts of every
    env of the device when any finished). Pass ``compact_reset=False`` for a batch stepped
    under ``vmap`` (the trainers vmap their seeds): there a data-dependent loop would run
    every env through the most iterations any of them needs. Each env's fresh start
    depends on its own key, params and carry only, so the states are the same bit for bit
    every way.

    **The carry.** A task's per-env carry (``State.carry``) survives every auto-reset:
    a finished env's carry is updated from its finished episode (the task's
    ``_carry_update``) before its fresh start, which reads it.
    """

    def __init__(
        self,
        env: Env,
        num_envs: int,
        randomize: bool = False,
        devices: int | None = None,
        compact_reset: bool = True,
        plan: Plan | None = None,
    ) -> None:
        if num_envs < 1:
            raise ValueError(f"num_envs must be >= 1, got {num_envs}")
        self.env = env
        self.num_envs = int(num_envs)
        self.randomize = bool(randomize)
        if plan is None:
            physics = getattr(env, "physics", "mjx")
            plan = make_plan(type(env), physics, self.num_envs, devices, vmapped=not compact_reset)
        #: how the batch runs: devices and reset mode (see "The plan")
        self.plan = plan
        #: the mesh the batch is spread over; ``None`` on one device
        self.mesh = plan.mesh

    @property
    def devices(self) -> int:
        """The number of devices the batch is spread over."""
        return 1 if self.mesh is None else self.mesh.size

    def on_one_device(self) -> BatchedEnv:
        """The same batch unspread, for callers that place it themselves (e.g. with
        :func:`jaxenvs.core.sharding.shard_jit`); see :mod:`jaxenvs.core.placement`."""
        if self.mesh is None:
            return self
        return BatchedEnv(
            self.env, self.num_envs, self.randomize, plan=dataclasses.replace(self.plan, devices=1)
        )

    def __getattr__(self, name: str) -> Any:
        raise AttributeError(f"BatchedEnv has no attribute {name!r}; the single env is at .env")

    observation_size = property(lambda self: self.env.observation_size)
    action_size = property(lambda self: self.env.action_size)
    observation_space = property(lambda self: self.env.observation_space)
    action_space = property(lambda self: self.env.action_space)
    discrete = property(lambda self: self.env.discrete)
    default_params = property(lambda self: self.env.default_params)
    episode_length = property(lambda self: self.env.episode_length)
    config = property(lambda self: self.env.config)
    scan_unroll = property(lambda self: self.env.scan_unroll)

    def fresh_starts(self, keys: jax.Array, params: Params = None, carry: Any = None) -> State:
        """Fresh starts of every env, env i's drawn with ``keys[i]`` as a reset and the
        auto-reset draw them (with ``randomize=True`` and no ``params``, its own params
        too), from ``carry`` (each env's, leading axis ``num_envs``; ``None``: a new one
        as :meth:`reset` makes); not spread over the batch's devices."""
        if carry is None:
            carry = jax.vmap(self.env.initial_carry, in_axes=(0, None))(keys, params)
        if self.randomize and params is None:
            # one split per env for its reset's 3 keys and its params key: the state is
            # env.reset(key, params)'s, the params drawn from split(key, 4)[3]
            split = jax.vmap(lambda k: jax.random.split(k, 4))(keys)
            params = jax.vmap(self.env.sample_params)(split[:, 3])
            state = jax.vmap(self.env._reset_from)(split, params, carry)
            return state.replace(params=params)
        split = jax.vmap(lambda k: jax.random.split(k, 3))(keys)
        return jax.vmap(self.env._reset_from, in_axes=(0, None, 0))(split, params, carry)

    def next_carry(self, state: State, done: jax.Array, params: Params = None) -> Any:
        """Each env's carry after ``state``: the task's update
        (:meth:`~jaxenvs.core.Env.next_carry`) from the finished episode where ``done``
        holds, unchanged elsewhere."""
        if not jax.tree.leaves(state.carry):
            return state.carry
        if state.params is not None:
            new = jax.vmap(self.env.next_carry)(state, state.params)
        else:
            new = jax.vmap(self.env.next_carry, in_axes=(0, None))(state, params)
        return jax.tree.map(functools.partial(_where, done), new, state.carry)

    def restart(self, state: State, mask: jax.Array, keys: jax.Array) -> State:
        """``state`` with the envs where ``mask`` holds started afresh with their ``keys``
        as the auto-reset starts them, each from its carry after the finished episode
        (:meth:`next_carry`): the whole State of a new episode, reward 0, flags False and
        a new episode's ``info`` (what a Gymnasium vector env's reset of a finished env
        is); the other envs unchanged."""

        def merge(old: State) -> State:
            old = old.replace(carry=self.next_carry(old, mask))
            fresh = self.fresh_starts(keys, None, old.carry)
            return merge_starts(self.env, old, fresh, functools.partial(_where, mask), True)

        return jax.lax.cond(jnp.any(mask), merge, lambda old: old, state)

    def reset(self, key: jax.Array, params: Params = None) -> State:
        """Reset all envs; returns a State with a leading ``num_envs`` axis."""
        check_key(key, f"batched {type(self.env).__name__}.reset")
        keys = jax.random.split(key, self.num_envs)
        if self.mesh is None:
            return self.fresh_starts(keys, params)
        return placement.spread(
            self.mesh, lambda k, _, p: self.fresh_starts(k, p), keys, (), params
        )

    def step(self, state: State, action: jax.Array, params: Params = None) -> State:
        """Step every env, then reset the finished ones (fresh random starts)."""
        check_state(state, (self.num_envs,), f"batched {type(self.env).__name__}.step")
        action = jnp.asarray(action)
        expected = (self.num_envs, *self.env.action_shape)
        if action.shape != expected:
            raise ValueError(
                f"batched {type(self.env).__name__}: expected actions of shape {expected}, "
                f"got {action.shape}"
            )
        if self.mesh is None:
            return self._step_batch(state, action, params)
        return placement.per_device(self.mesh, self._step_batch, state, action, params)

    def _step_batch(self, state: State, action: jax.Array, params: Params) -> State:
        """The step of ``state``'s envs (one device's), each finished env reset as the
        plan says."""
        if state.params is not None:
            nxt = jax.vmap(self.env.step)(state, action, state.params)
        else:
            nxt = jax.vmap(self.env.step, in_axes=(0, 0, None))(state, action, params)
        done = nxt.done
        nxt = nxt.replace(carry=self.next_carry(nxt, done, params))
        per_device = done.shape[0]
        slots = self.plan.reset_slots(per_device)

        def reset_all(nxt: State) -> State:
            fresh = self.fresh_starts(nxt.key, params, nxt.carry)
            merged = merge_starts(self.env, nxt, fresh, functools.partial(_where, done))
            return _zero_counters(merged, done)

        if slots == 0:
            return jax.lax.cond(jnp.any(done), reset_all, lambda s: s, nxt)
        # the device's finished envs, in order, in chunks of `slots` places (the places
        # past the last finished env point past the end and are dropped when scattered
        # back); a chunk a loop iteration, one copy of the fresh starts
        chunks = -(-per_device // slots)
        index = jnp.nonzero(done, size=chunks * slots, fill_value=per_device)[0]
        needed = -(-done.sum() // slots)
        keys, carries = nxt.key, nxt.carry

        def reset_chunk(c: jax.Array, state: State) -> State:
            where = jax.lax.dynamic_slice_in_dim(index, c * slots, slots)

            def pick(x: jax.Array) -> jax.Array:
                return x[jnp.minimum(where, per_device - 1)]

            fresh = self.fresh_starts(pick(keys), params, jax.tree.map(pick, carries))

            def put(new: jax.Array, old: jax.Array) -> jax.Array:
                return old.at[where].set(new, mode="drop")

            return merge_starts(self.env, state, fresh, put)

        return _zero_counters(jax.lax.fori_loop(0, needed, reset_chunk, nxt), done)

    def __repr__(self) -> str:
        return f"BatchedEnv({self.env!r}, num_envs={self.num_envs}, devices={self.devices})"


def merge_starts(
    env: Env,
    old: State,
    fresh: State,
    put: Callable[[jax.Array, jax.Array], jax.Array],
    whole: bool = False,
) -> State:
    """``old`` with fresh starts taken from ``fresh`` by ``put(fresh_leaf, old_leaf)``
    (which picks, per env, the fresh leaf for the envs that start again): the one merge
    of every auto-reset (:class:`BatchedEnv`'s step, :meth:`BatchedEnv.restart`, the
    adapters). ``whole=False`` (an auto-reset inside a step) takes the physics, ``obs``,
    ``extras``, ``time``, ``key``, ``params`` and ``carry`` and keeps the finished
    transition's reward, flags and ``info``; ``whole=True`` takes every field (a new
    episode's State)."""
    data = env.sim.select_data(put, fresh.data, old.data)
    if whole:
        rest = jax.tree.map(put, fresh.replace(data=None), old.replace(data=None))
        return rest.replace(data=data)
    obs, extras, time, key, params, carry = jax.tree.map(
        put,
        (fresh.obs, fresh.extras, fresh.time, fresh.key, fresh.params, fresh.carry),
        (old.obs, old.extras, old.time, old.key, old.params, old.carry),
    )
    return old.replace(
        data=data, obs=obs, extras=extras, time=time, key=key, params=params, carry=carry
    )


def _zero_counters(state: State, done: jax.Array) -> State:
    """``state`` with the episode counters of the ``done`` envs zeroed."""
    info = dict(state.info)
    info["episode_return"] = jnp.where(done, 0.0, state.info["episode_return"])
    info["episode_length"] = jnp.where(done, 0, state.info["episode_length"])
    return state.replace(info=info)


def _where(done: jax.Array, new: jax.Array, old: jax.Array) -> jax.Array:
    return jnp.where(done.reshape(done.shape + (1,) * (old.ndim - 1)), new, old)
