"""jaxenvs: JAX-accelerated, vectorised robot RL environments on MuJoCo MJX.

The public surface::

    import jaxenvs
    jaxenvs.list_envs()
    env = jaxenvs.make("CartpoleBalance-v0", episode_length=500)
    state = env.reset(key); state = env.step(state, action)
    benv = jaxenvs.make("CartPole-v0", num_envs=4096)   # batched, auto-resetting
"""

# ``mujoco.mjx`` is imported when a model is first built (jaxenvs.physics.sim.mjx_module),
# not here: a process that only lists envs or reads the CLI's help does not pay for it.
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
