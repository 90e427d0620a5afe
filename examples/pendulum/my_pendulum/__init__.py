"""my_pendulum: a package of one's own that adds a task to jaxenvs when imported."""

import jaxenvs
from my_pendulum.task import Pendulum, PendulumConfig

jaxenvs.register(
    "MyPendulum-v0",
    Pendulum,
    PendulumConfig(),
    description="pendulum swing-up (Gymnasium Pendulum-v1's task on MJX), 200 steps",
    overwrite=True,  # importing twice (e.g. by module path and by entry point) is harmless
)

__all__ = ["Pendulum", "PendulumConfig"]
