"""The id table: every registered env id -> (task class, default config, metadata).

An explicit table, filled in one place (``_builtin``) for our own tasks and by
:func:`register` for users' tasks; nothing registers itself as an import side effect
elsewhere in jaxenvs. Views of the table kept elsewhere (the Gymnasium facade's ids) follow
it through :func:`add_listener`; this module imports none of them.

Users' packages register their tasks when imported. Two ways make that happen for code
that only knows an id (the command line, a run directory's config): an id of the form
``"module:Id"`` imports ``module`` first (Gymnasium's convention), and an installed
package can declare its registering module as an entry point of the group
``jaxenvs.envs`` (loaded once, by :func:`list_envs` and on an unknown id).
"""

from __future__ import annotations

import dataclasses
import importlib
import importlib.metadata
import warnings
from collections.abc import Callable
from typing import Any

from jaxenvs.config import ConfigError, apply_overrides
from jaxenvs.core import BatchedEnv, Env, TaskConfig
from jaxenvs.core.plan import plan


@dataclasses.dataclass(frozen=True)
class EnvSpec:
    """One registered id.

    Attributes:
      id: the env id, e.g. ``"CartPole-v0"``.
      factory: ``factory(config) -> Env``; usually the task class.
      config: the default config of this id (a frozen dataclass).
      description: one line for ``jaxenvs list``.
      reward_threshold: return at which the task counts as solved, if meaningful.
    """

    id: str
    factory: Callable[[Any], Env]
    config: TaskConfig
    description: str = ""
    reward_threshold: float | None = None


_REGISTRY: dict[str, EnvSpec] = {}
#: called with every spec :func:`register` stores (see :func:`add_listener`)
_LISTENERS: list[Callable[[EnvSpec], None]] = []


def register(
    env_id: str,
    factory: Callable[[Any], Env],
    config: TaskConfig,
    description: str = "",
    reward_threshold: float | None = None,
    *,
    overwrite: bool = False,
) -> EnvSpec:
    """Register a task under ``env_id`` so that :func:`make` (and the Gymnasium facade,
    the agents and the command line) can build it.

    Args:
      env_id: the id, ``Name-vN``.
      factory: called with the (overridden) config; returns an :class:`Env`.
      config: the default config instance.
      description: one line for ``jaxenvs list``.
      reward_threshold: the "solved" return, if meaningful.
      overwrite: replace an existing registration instead of raising.
    """
    if env_id in _REGISTRY and not overwrite:
        raise ValueError(f"env id {env_id!r} is already registered (pass overwrite=True)")
    spec = EnvSpec(env_id, factory, config, description, reward_threshold)
    _REGISTRY[env_id] = spec
    for listener in _LISTENERS:
        listener(spec)
    return spec


def add_listener(listener: Callable[[EnvSpec], None]) -> None:
    """Call ``listener(spec)`` for every id registered so far and every later
    :func:`register` (re-registrations included).

    This is how other views of the table follow it without this module importing them:
    the Gymnasium facade (:mod:`jaxenvs.compat.gymnasium`) adds itself when imported.
    """
    _LISTENERS.append(listener)
    for spec in list(_REGISTRY.values()):
        listener(spec)


ENTRY_POINT_GROUP = "jaxenvs.envs"
_plugins_loaded = False
_builtins_registered = False


def load_plugins() -> None:
    """Import (once) the modules installed packages declare under ``jaxenvs.envs``.

    A package registers its tasks on import; its ``pyproject.toml`` declares e.g.
    ``[project.entry-points."jaxenvs.envs"] my_tasks = "my_tasks"``. A plugin that fails
    to import is reported with a warning and skipped.
    """
    global _plugins_loaded
    if _plugins_loaded or not _builtins_registered:  # a plugin imports a complete jaxenvs
        return
    _plugins_loaded = True
    for entry in importlib.metadata.entry_points(group=ENTRY_POINT_GROUP):
        try:
            entry.load()
        except Exception as err:  # noqa: BLE001 - one broken plugin must not break jaxenvs
            warnings.warn(
                f"jaxenvs plugin {entry.name!r} ({entry.value}) failed to load: {err}",
                stacklevel=2,
            )


def list_envs() -> list[str]:
    """All registered env ids, in registration order (installed plugins included)."""
    load_plugins()
    return list(_REGISTRY)


def spec(env_id: str) -> EnvSpec:
    """The :class:`EnvSpec` of ``env_id``; unknown ids raise with the list of valid ones.

    ``"module:Id"`` imports ``module`` (which registers ``Id``) and looks up ``Id``.
    """
    module, sep, name = env_id.rpartition(":")
    if sep:
        try:
            importlib.import_module(module)
        except ImportError as err:
            raise ValueError(f"env id {env_id!r}: cannot import {module!r}: {err}") from err
        env_id = name
    if env_id not in _REGISTRY:
        load_plugins()
    try:
        return _REGISTRY[env_id]
    except KeyError:
        raise ValueError(
            f"unknown env id {env_id!r}; registered ids: {', '.join(_REGISTRY)}"
        ) from None


def make_config(
    env_id: str, overrides: dict[str, Any] | None = None, source: str = "make() overrides"
) -> TaskConfig:
    """The default config of ``env_id`` with ``overrides`` applied and validated."""
    return apply_overrides(spec(env_id).config, overrides or {}, source)


def make(
    env_id: str,
    num_envs: int | None = None,
    randomize: bool = False,
    devices: int | None = None,
    **overrides: Any,
) -> Env | BatchedEnv:
    """Build the env registered as ``env_id``.

    Args:
      env_id: a registered id (see :func:`list_envs`).
      num_envs: if given, a :class:`BatchedEnv` of that many auto-resetting envs.
      randomize: with ``num_envs``, draw per-env params at every reset.
      devices: with ``num_envs``, how many local devices the batch is spread over
        (default: all that ``num_envs`` divides over; ``1``: none; see
        :func:`jaxenvs.core.placement.batch_devices`).
      **overrides: any field of the task's config (``episode_length=500``,
        ``physics="c"``, ...); an unknown key raises :class:`ConfigError` listing the
        valid ones. ``physics`` is resolved for this batch size
        (:func:`jaxenvs.physics.resolve_engine`).
    """
    factory = spec(env_id).factory
    if num_envs is None and (randomize or devices is not None):
        raise ConfigError("randomize and devices need num_envs (a batched env)")
    if num_envs is not None and (
        isinstance(num_envs, bool) or not isinstance(num_envs, int) or num_envs < 1
    ):
        raise ConfigError(f"num_envs must be a positive integer, got {num_envs!r}")
    config = make_config(env_id, overrides)
    if not isinstance(factory, type):  # a factory function: the env resolves its engine
        env = factory(config)
        return env if num_envs is None else BatchedEnv(env, num_envs, randomize, devices)
    # the plan, once: engine, devices and reset mode (jaxenvs.core.plan)
    the_plan = plan(factory, getattr(config, "physics", "auto"), num_envs, devices)
    if getattr(config, "physics", the_plan.physics) != the_plan.physics:
        config = dataclasses.replace(config, physics=the_plan.physics)
    env = factory(config)
    if num_envs is None:
        return env
    return BatchedEnv(env, num_envs, randomize=randomize, plan=the_plan)


def _builtin() -> None:
    from jaxenvs.tasks import cartpole, hexapod, reacher

    register(
        "CartPole-v0",
        cartpole.CartPole,
        cartpole.CartPoleConfig(),
        "classic balance: +1 per step, ends past 12 deg or 2.4 m, 500 steps",
        reward_threshold=475.0,
    )
    register(
        "CartpoleStayUp-v0",
        cartpole.CartpoleStayUp,
        cartpole.StayUpConfig(),
        "ROS-course stay-up: velocity-increment commands, +1 per step",
    )
    register(
        "CartpoleBalance-v0",
        cartpole.CartpoleBalance,
        cartpole.BalanceConfig(),
        "dense balance reward in [0, 1], continuous force, 1000 steps",
        reward_threshold=950.0,
    )
    register(
        "CartpoleSwingup-v0",
        cartpole.CartpoleBalance,
        cartpole.BalanceConfig(swing_up=True),
        "swing up from hanging, dense reward, continuous force, 1000 steps",
        reward_threshold=800.0,
    )
    register(
        "Reacher-v0",
        reacher.Reacher,
        reacher.ReacherConfig(),
        "2-link planar arm reaching a random target: -distance - control cost, 50 steps",
        reward_threshold=-3.75,
    )
    register(
        "HexapodWalk-v0",
        hexapod.HexapodWalk,
        hexapod.WalkConfig(),
        "6 legs x 3 servos walk from target to target: progress - energy + alive, 1000 steps",
    )
    register(
        "HexapodOneLeg-v0",
        hexapod.HexapodOneLeg,
        hexapod.OneLegConfig(),
        "one hexapod leg on a fixed base: -(tip - target)^2, 100 steps",
    )
    register(
        "HexapodJoystick-v0",
        hexapod.HexapodJoystick,
        hexapod.JoystickConfig(),
        "6 legs x 3 servos follow a velocity command from onboard sensors, 1000 steps",
    )
    register(
        "HexapodJoystickRough-v0",
        hexapod.HexapodJoystickRough,
        hexapod.JoystickRoughConfig(),
        "the joystick on a terrain of levels x types, a per-env level curriculum, 400 steps",
    )
    register(
        "HexapodWalkRough-v0",
        hexapod.HexapodWalkRough,
        hexapod.WalkRoughConfig(),
        "the walker on the same terrain and curriculum, targets on its own tile, 400 steps",
    )


_builtin()
_builtins_registered = True
