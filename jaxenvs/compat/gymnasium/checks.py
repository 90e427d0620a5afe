"""Host-side checks of the facade's input, each failing with a one-line error."""

from __future__ import annotations

import os
from typing import Any

import numpy as np
from gymnasium.error import ClosedEnvironmentError
from gymnasium.utils import seeding
from gymnasium.vector import AutoresetMode

from jaxenvs.core import Env

RENDER_MODES = ["rgb_array"]
#: what the entry points declare to ``gymnasium.make``: "human" is listed so that it reaches
#: the constructor (which explains what to do) instead of being silently rerouted.
DECLARED_MODES = ["rgb_array", "human"]


def _space_text(env: Env, num_envs: int | None = None) -> str:
    space = env.action_space
    if num_envs is None:
        return str(space)
    return f"{num_envs} actions of {space}, shape {(num_envs, *env.action_shape)}"


def check_action(env: Env, action: Any, num_envs: int | None = None) -> np.ndarray:
    """Validate ``action`` on the host; returns it as a numpy array of the env's dtype.

    Raises ``ValueError`` naming the expected space for a wrong shape or dtype, or a
    discrete action out of range.
    """
    lead = () if num_envs is None else (num_envs,)
    expected = (*lead, *env.action_shape)

    def what() -> str:  # built only for an error: a space's text costs ~0.1 ms a step
        return _space_text(env, num_envs)

    if isinstance(action, (bool, np.bool_)):
        raise ValueError(f"expected an action in {what()}, got a bool")
    try:
        arr = np.asarray(action)
    except (TypeError, ValueError) as err:
        raise ValueError(f"expected an action in {what()}, got {type(action).__name__}") from err
    if arr.shape != expected:
        raise ValueError(
            f"expected an action in {what()} (shape {expected}), got shape {arr.shape}"
        )
    if env.discrete:
        if not np.issubdtype(arr.dtype, np.integer):
            raise ValueError(f"expected an integer action in {what()}, got dtype {arr.dtype}")
        if arr.size and (arr.min() < 0 or arr.max() >= env.action_size):
            raise ValueError(
                f"discrete action out of range for {what()}: valid actions are "
                f"0..{env.action_size - 1}, got {arr.min() if arr.min() < 0 else arr.max()}"
            )
        return arr.astype(np.int32, copy=False)
    if not np.issubdtype(arr.dtype, np.floating):
        raise ValueError(f"expected a floating-point action in {what()}, got dtype {arr.dtype}")
    return arr.astype(np.float32, copy=False)


def display_available() -> bool:
    """True where a window can open (``DISPLAY`` or ``WAYLAND_DISPLAY`` is set)."""
    return bool(os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY"))


def check_render_mode(render_mode: str | None, human_ok: bool = False) -> None:
    """Refuse a render mode the env cannot serve (``human_ok``: it has a window)."""
    if render_mode is None or render_mode in RENDER_MODES:
        return
    if render_mode == "human":
        if not display_available():
            raise ValueError(
                "render_mode='human' needs a display and none was found (DISPLAY and "
                "WAYLAND_DISPLAY are unset); use render_mode='rgb_array' (frames, videos "
                "through gymnasium.wrappers.RecordVideo or `jaxenvs render`)"
            )
        if human_ok:  # the single env draws in MuJoCo's viewer (jaxenvs.render.viewer)
            return
        raise ValueError(
            "render_mode='human' has no native window in the Gymnasium facade yet; wrap an "
            "rgb_array env instead: gymnasium.wrappers.HumanRendering(gymnasium.make(id, "
            "render_mode='rgb_array'))"
        )
    raise ValueError(f"unsupported render_mode {render_mode!r}; supported: {RENDER_MODES}")


def check_options(options: dict[str, Any] | None, allowed: tuple[str, ...]) -> dict[str, Any]:
    """``options`` of a reset as a dict, refusing keys outside ``allowed``."""
    if options is None:
        return {}
    if not isinstance(options, dict):
        raise TypeError(f"options must be a dict, got {type(options).__name__}")
    unknown = sorted(set(options) - set(allowed))
    if unknown:
        raise ValueError(
            f"unsupported reset options {unknown}; supported: {list(allowed) or 'none'}"
        )
    return options


def seed32(rng: np.random.Generator) -> np.uint32:
    """A uint32 drawn from Gymnasium's ``np_random``: the seed of the next JAX key."""
    return rng.integers(0, 2**32, dtype=np.uint32)


def _is_seed(seed: Any) -> bool:
    return isinstance(seed, (int, np.integer)) and not isinstance(seed, bool) and bool(seed >= 0)


def env_seeds(seed: Any, num_envs: int, rng: np.random.Generator) -> np.ndarray:
    """The uint32 seed of each env's JAX key for a vector env's ``reset(seed=)``, as
    ``SyncVectorEnv`` seeds its envs: ``None``: every env's drawn from ``rng``; an int
    ``s``: env i's from ``s + i``; a list of ``num_envs`` ints or Nones: env i's from its
    entry (drawn from ``rng`` where None). Env i seeded with ``s`` starts where a single
    env's ``reset(seed=s)`` starts. A bad seed raises ``ValueError`` in one line."""
    if seed is None:
        seeds: list[Any] = [None] * num_envs
    elif _is_seed(seed):
        seeds = [int(seed) + i for i in range(num_envs)]
    elif isinstance(seed, (list, tuple, np.ndarray)) and all(
        s is None or _is_seed(s) for s in seed
    ):
        seeds = list(seed)
    else:
        raise ValueError(
            "seed must be None, a non-negative int, or a list of non-negative ints or Nones "
            f"(one per env), got {seed!r}"
        )
    if len(seeds) != num_envs:
        raise ValueError(f"seed: a list of {num_envs} seeds (one per env), got {len(seeds)}")
    out = np.empty(num_envs, np.uint32)
    drawn = [i for i, s in enumerate(seeds) if s is None]
    out[drawn] = rng.integers(0, 2**32, size=len(drawn), dtype=np.uint32)
    for i, s in enumerate(seeds):
        if s is not None:
            out[i] = seed32(seeding.np_random(int(s))[0])
    return out


def check_open(closed: bool, env_id: str) -> None:
    """Refuse to use an env after ``close()``."""
    if closed:
        raise ClosedEnvironmentError(f"jaxenvs/{env_id} was closed; make a new env to go on")


def render_fps(env: Env) -> int:
    """Frames per second of real time: one frame per control step."""
    return max(1, round(1.0 / env.control_dt))


def autoreset_mode(mode: Any) -> AutoresetMode:
    """``mode`` as an ``AutoresetMode``: the member itself, its value (``"SameStep"``) or its
    name in any case (``"same_step"``)."""
    if isinstance(mode, AutoresetMode):
        return mode
    if isinstance(mode, str):
        for member in AutoresetMode:
            if mode in (member.value, member.name.lower(), member.name):
                return member
    names = [m.name.lower() for m in AutoresetMode]
    raise ValueError(
        f"autoreset_mode must be a gymnasium.vector.AutoresetMode or one of {names}, got {mode!r}"
    )


def check_reset_mask(mask: Any, num_envs: int) -> np.ndarray:
    """``options["reset_mask"]`` checked as ``SyncVectorEnv`` checks it: a numpy bool array
    of shape ``(num_envs,)`` with at least one True value."""
    if not isinstance(mask, np.ndarray):
        raise TypeError(f"options['reset_mask'] must be a numpy array, got {type(mask)}")
    if mask.shape != (num_envs,) or mask.dtype != np.bool_:
        raise ValueError(
            f"options['reset_mask'] must be a bool array of shape ({num_envs},), "
            f"got {mask.dtype} {mask.shape}"
        )
    if not mask.any():
        raise ValueError("options['reset_mask'] must contain at least one True value")
    return mask
