"""Which physics engine a test steps with.

Tests of task logic (observations, rewards, resets, the battery, the command line) run
on MuJoCo's C engine where JAX runs on the CPU: its reset and step compile in about a
second, as no physics is compiled, where MJX's take 3-15 s. ``physics="auto"`` (what
``jaxenvs.make`` does by default) already picks it for the built-in tasks; a user's task
(``examples/pendulum``) defaults to MJX, so its tests ask for :data:`TASK_LOGIC`. Tests of
MJX itself (parity with MuJoCo C, sharding, MJX's speed hints) say ``physics="mjx"``.
"""

from __future__ import annotations

import jax

#: the engine for tests of task logic: the C engine on a CPU, MJX on an accelerator
TASK_LOGIC = "c" if jax.default_backend() == "cpu" else "mjx"
