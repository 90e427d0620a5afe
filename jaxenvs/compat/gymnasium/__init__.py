"""Gymnasium facade: every jaxenvs id as a ``gymnasium.Env`` and a ``gymnasium.vector.VectorEnv``.

After ``import jaxenvs`` each registered id ``X`` is also registered with Gymnasium as
``jaxenvs/X`` (with ``max_episode_steps`` = the task's episode length and the id's
``reward_threshold``), including ids registered later through :func:`jaxenvs.register`::

    env = gymnasium.make("jaxenvs/CartPole-v0", render_mode="rgb_array")
    envs = gymnasium.make_vec("jaxenvs/CartPole-v0", num_envs=1024,
                              vectorization_mode="vector_entry_point")

Keyword arguments of ``make``/``make_vec`` other than ``render_mode``, ``width``,
``height``, ``camera`` (and ``autoreset_mode``, ``randomize`` and ``devices`` for the
vector env) override fields of the task's config, as in :func:`jaxenvs.make`.

:class:`JaxEnv` (one env): numpy float32 observations, Python scalars in the 5-tuple,
Gymnasium seeding (``reset(seed=)`` seeds ``np_random``, which draws the JAX key of every
reset). :class:`~jaxenvs.compat.gymnasium.vector.JaxVectorEnv` (N envs): one jitted step
and one device-to-host copy per step for all envs, ``AutoresetMode.NEXT_STEP`` by default
(as Gymnasium's own vector envs, so its vector wrappers work), ``SAME_STEP`` or
``DISABLED`` by keyword.

Both keep their state in one representation, :class:`~jaxenvs.compat.gymnasium.words.Words`:
a few flat buffers of 32-bit words, which each step's jitted call takes (and donates, but
for a SAME_STEP vector env's), with the leaves the host reads (observation, reward, flags,
info) first, so a step's results are read from the first buffer of the new state. One
env's buffers hold at most :data:`SEQUENTIAL_BYTES` each, which keeps XLA's CPU runtime on
the calling thread, where a single small env's step costs ~3x less. The jitted functions
are built once per task config and batch, and shared by the instances made while they stay
in a bounded cache (:mod:`~jaxenvs.compat.gymnasium.programs`).

Info keys (single env values are Python scalars, vector values arrays with ``_key``
masks): ``nan_actions``, ``diverged`` and the task's metrics (e.g. ``distance``).
"""

from __future__ import annotations

import warnings
from typing import Any

import gymnasium
import jax
import numpy as np
from gymnasium.error import ResetNeeded

from jaxenvs import registry
from jaxenvs.compat.gymnasium import checks
from jaxenvs.compat.gymnasium.checks import RENDER_MODES, check_action
from jaxenvs.compat.gymnasium.programs import BASE_INFO_KEYS, CACHE_SIZE, compiled
from jaxenvs.compat.gymnasium.vector import JaxVectorEnv
from jaxenvs.compat.gymnasium.words import SEQUENTIAL_BYTES, Bufs
from jaxenvs.core import Env, State

__all__ = [
    "BASE_INFO_KEYS",
    "CACHE_SIZE",
    "PREFIX",
    "RENDER_MODES",
    "SEQUENTIAL_BYTES",
    "JaxEnv",
    "JaxVectorEnv",
    "check_action",
    "gym_id",
    "compiled",
    "register_spec",
]

PREFIX = "jaxenvs/"
_FLOAT32 = np.dtype(np.float32)


def gym_id(env_id: str) -> str:
    """The Gymnasium id of a jaxenvs id: ``"jaxenvs/" + env_id``."""
    return PREFIX + env_id


def register_spec(spec: registry.EnvSpec) -> None:
    """Register ``jaxenvs/<spec.id>`` with Gymnasium (replacing an earlier registration)."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # Gymnasium warns when an id is re-registered
        gymnasium.register(
            id=gym_id(spec.id),
            entry_point=f"{__name__}:JaxEnv",
            vector_entry_point=f"{__name__}:JaxVectorEnv",
            max_episode_steps=int(spec.config.episode_length),
            reward_threshold=spec.reward_threshold,
            kwargs={"env_id": spec.id},
        )


class JaxEnv(gymnasium.Env):
    """One jaxenvs task as a standard ``gymnasium.Env`` (see the module docstring).

    Args:
      env_id: a registered jaxenvs id (without the ``jaxenvs/`` prefix).
      render_mode: ``None``, ``"rgb_array"``, or ``"human"``: MuJoCo's viewer window
        (:mod:`jaxenvs.render.viewer`), drawn in real time at every reset and step; needs a
        display (refused with a clear message where there is none).
      width, height, camera: frame size and camera for ``render()`` (see
        :mod:`jaxenvs.render`).
      **overrides: fields of the task's config.
    """

    metadata: dict[str, Any] = {"render_modes": checks.DECLARED_MODES, "render_fps": 50}

    def __init__(
        self,
        env_id: str,
        render_mode: str | None = None,
        width: int = 640,
        height: int = 480,
        camera: str | int | None = None,
        **overrides: Any,
    ) -> None:
        checks.check_render_mode(render_mode, human_ok=True)
        self._fns = compiled(env_id, overrides)
        self.env_id = env_id
        self._overrides = dict(overrides)
        self._closed = False
        self.jax_env: Env = self._fns.env
        self.observation_space = self.jax_env.observation_space
        self.action_space = self.jax_env.action_space
        self.render_mode = render_mode
        # "human" is offered (and so exercised by Gymnasium's env checker) only where a
        # display exists; the class metadata always lists it so gymnasium.make passes it on.
        human = ["human"] if checks.display_available() else []
        self.metadata = {
            "render_modes": [*checks.RENDER_MODES, *human],
            "render_fps": checks.render_fps(self.jax_env),
        }
        self._render_args = (width, height, camera)
        self._renderer: Any = None
        self._bufs: Bufs | None = None
        self._words = self._fns.words
        #: the shape of a continuous action (checked at once when it comes as float32)
        self._float_shape = None if self.jax_env.discrete else self.jax_env.action_shape

    @property
    def state(self) -> State | None:
        """The current functional-API state (``None`` before the first reset)."""
        return None if self._bufs is None else self._fns.unpack(self._bufs)

    def reset(
        self, *, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[np.ndarray, dict[str, Any]]:
        checks.check_open(self._closed, self.env_id)
        super().reset(seed=seed)
        checks.check_options(options, ())
        self._bufs = self._fns.reset(checks.seed32(self.np_random))
        if self.render_mode == "human":
            self.render()
        return self._words.report(self._bufs)[0], {}

    def step(self, action: Any) -> tuple[np.ndarray, float, bool, bool, dict[str, Any]]:
        bufs = self._bufs
        if bufs is None:
            checks.check_open(self._closed, self.env_id)
            raise ResetNeeded("Cannot call env.step() before calling env.reset()")
        # a float32 array of the action's shape goes straight in; anything else is checked
        # and converted. ``is``: numpy gives an ordinary float32 array its one shared
        # float32 dtype (an unpickled or deep-copied array has its own, and takes the
        # checked path, with the same result)
        if (
            type(action) is not np.ndarray
            or action.dtype is not _FLOAT32
            or action.shape != self._float_shape
        ):
            action = checks.check_action(self.jax_env, action)
        self._bufs = bufs = self._fns.step(bufs, action)
        if self.render_mode == "human":
            self.render()
        return self._words.report(bufs)

    def render(self) -> np.ndarray | None:  # type: ignore[override]
        if self.render_mode is None:
            gymnasium.logger.warn(
                "render() called without a render_mode; pass render_mode='rgb_array' to make()"
            )
            return None
        checks.check_open(self._closed, self.env_id)
        if self._bufs is None:
            raise ResetNeeded("Cannot call env.render() before calling env.reset()")
        if self.render_mode == "human":
            if self._renderer is None:
                from jaxenvs.render.viewer import StateViewer

                self._renderer = StateViewer(self.jax_env)
            self._renderer.show(self.state)
            return None
        if self._renderer is None:
            from jaxenvs.render import Renderer

            self._renderer = Renderer(self.jax_env, *self._render_args)
        return self._renderer.render_state(self.state)

    def close(self) -> None:
        """Release the renderer and the state; a closed env refuses ``reset``, ``step``
        and ``render`` (``ClosedEnvironmentError``)."""
        if self._renderer is not None:
            self._renderer.close()
            self._renderer = None
        self._bufs = None
        self._closed = True
        super().close()

    def __getstate__(self) -> dict[str, Any]:
        """What a copy or a pickle keeps: the construction arguments, the seeding and the
        state (on the host); the jitted functions and the renderer are rebuilt."""
        kept = {k: v for k, v in self.__dict__.items() if k not in _REBUILT}
        kept["_bufs"] = None if self._bufs is None else tuple(np.array(b) for b in self._bufs)
        return kept

    def __setstate__(self, kept: dict[str, Any]) -> None:
        self.__dict__.update(kept)
        self._fns = compiled(self.env_id, self._overrides)
        self.jax_env = self._fns.env
        self._words = self._fns.words
        self._renderer = None
        if self._bufs is not None:
            self._bufs = tuple(jax.device_put(b) for b in self._bufs)


#: a single env's attributes a copy or pickle rebuilds instead of copying
_REBUILT = frozenset({"_fns", "jax_env", "_words", "_renderer"})


registry.add_listener(register_spec)
