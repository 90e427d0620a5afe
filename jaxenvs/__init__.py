"""jaxenvs: JAX-accelerated, vectorised robot RL environments on MuJoCo MJX.

The public surface::

    import jaxenvs
    jaxenvs.list_envs()
    env = jaxenvs.make("CartpoleBalance-v0", episode_length=500)
    state = env.reset(key); state = env.step(state, action)
    benv = jaxenvs.make("CartPole-v0", num_envs=4096)   # batched, auto-resetting
"""

import contextlib as _contextlib
import io as _io

# mujoco.mjx prints a notice when its optional Warp backend is absent; keep imports quiet.
with _contextlib.redirect_stdout(_io.StringIO()):
    from mujoco import mjx as _mjx  # noqa: F401

# the Gymnasium facade registers every id (and every later one) as ``jaxenvs/<id>``
from jaxenvs.compat import gymnasium as _gymnasium  # noqa: F401
from jaxenvs.config import ConfigError
from jaxenvs.core import BatchedEnv, Env, State
from jaxenvs.registry import list_envs, make, register, spec

__all__ = [
    "BatchedEnv",
    "ConfigError",
    "Env",
    "State",
    "list_envs",
    "make",
    "register",
    "spec",
]
__version__ = "0.1.0"
