"""Core types: the env state, the task base class, and the batched auto-resetting env.

A task is a pair of pure functions ``reset(key, params) -> State`` and
``step(state, action, params) -> State``. Subclasses of :class:`Env` supply hooks (the
task layer) over a :class:`jaxenvs.physics.sim.Sim` (the sim and robot layers):

* ``_init(key, params) -> (data, extras)``: the initial-state distribution;
* ``_act(key, data, extras, action, params) -> (data, extras)``: map a (sanitised)
  action to controls and advance the physics one control step; ``key`` is for action
  noise or delay and pushes;
* ``_observe(key, data, extras, params) -> obs``; ``key`` is for observation noise;
* ``_reward(prev_data, data, action, extras, params) -> (reward, metrics)``;
* ``_terminated(data, extras, params) -> bool`` (default: never).

``extras`` is the task's own state (targets, commands, ...): a frozen
:class:`flax.struct.PyTreeNode` of arrays whose structure is fixed per task
(:class:`NoExtras` for tasks without one).

**Keys.** ``reset`` splits its key once into (the state's next key, the init key, the
observation key); ``step`` splits ``state.key`` once into (the next key, the act key,
the observation key). Each hook gets its own subkey, used once; the first subkey becomes
``state.key`` and drives every later step and auto-reset. A hook that does not draw
random numbers ignores its key, and the task's trajectories are the same as if it had
none.

:class:`Env` adds what every task shares: action validation and sanitisation, episode
counters, truncation at the episode length, divergence detection, and a fixed ``info``.

``info`` keys (all arrays, present after every reset and step):

=================  =====================================================================
``episode_return``  return accumulated so far in the current episode
``episode_length``  steps taken so far in the current episode
``final_obs``       the observation the last transition really ended in; equal to
                    ``obs`` except right after an auto-reset, where it keeps the finished
                    episode's last observation (use it to bootstrap on truncation)
``final_return``    return of the episode the last transition belongs to
``final_length``    length of the episode the last transition belongs to
``nan_actions``     1 if the last action held a NaN/inf (it was replaced by zeros)
``diverged``        True if the physics state became non-finite or passed the divergence
                    bound; such an env is terminated (and reset when batched)
(task metrics)      fixed per task, e.g. ``distance`` for the reacher: of the last
                    transition (zero after a reset; after an auto-reset, still the
                    finished episode's last transition's)
=================  =====================================================================
"""

from jaxenvs.core.batch import BatchedEnv
from jaxenvs.core.env import (
    STANDARD_INFO_KEYS,
    Env,
    NoExtras,
    State,
    TaskConfig,
    check_key,
    check_state,
)
from jaxenvs.core.plan import Plan, plan

__all__ = [
    "STANDARD_INFO_KEYS",
    "BatchedEnv",
    "Env",
    "NoExtras",
    "Plan",
    "State",
    "TaskConfig",
    "check_key",
    "check_state",
    "plan",
]
