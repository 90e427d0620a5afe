"""A run's config: the YAML sections, their resolution and the algorithm table.

An algorithm is a module in :data:`ALGORITHMS` exposing a frozen config dataclass (with
at least ``num_envs`` and ``total_steps`` fields, which ``--num-envs`` / ``--total-steps``
override) and ``make_trainer(env, config) -> Trainer`` (see :mod:`jaxenvs.agents.base`).

A config file is YAML with separate sections, all optional::

    algo: qlearning            # qlearning | sarsa | ppo
    env:   {id: CartPole-v0, episode_length: 500}   # id + task config overrides
    agent: {alpha: 0.1, ...}   # the algorithm's config fields
    train: {seed: 0, num_seeds: 1, ...}              # RunConfig fields

:func:`resolve_config` merges defaults, the file and command-line values into a validated
:class:`ResolvedConfig`; :func:`engine_resolved` pins ``physics="auto"`` to the engine it
picks on this machine (what a run's ``config.yaml`` records); :func:`build` makes the env
and trainer of a resolved config. The names of a run directory's files are here too.
"""

from __future__ import annotations

import dataclasses
import importlib
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any

import jax
import jax.numpy as jnp

from jaxenvs import registry
from jaxenvs.agents.base import Trainer
from jaxenvs.config import (
    ConfigError,
    apply_overrides,
    config_to_dict,
    load_yaml,
    name_some,
    require,
)
from jaxenvs.core import Env
from jaxenvs.physics import with_engine


@dataclasses.dataclass(frozen=True)
class AlgoEntry:
    """Where an algorithm lives: module path and the name of its config class."""

    module: str
    config_class: str
    make_trainer: str = "make_trainer"


#: ``--algo`` name -> module exposing its config class and ``make_trainer``.
ALGORITHMS: dict[str, AlgoEntry] = {
    "qlearning": AlgoEntry("jaxenvs.agents.tabular", "QLearningConfig"),
    "sarsa": AlgoEntry("jaxenvs.agents.tabular", "SarsaConfig"),
    "ppo": AlgoEntry("jaxenvs.agents.ppo", "PPOConfig"),
}

SECTIONS = ("algo", "env", "agent", "train")
#: the shipped configs: ``<algo>_<env id>.yaml`` (the default of that pair) and
#: ``<algo>_<env id>.<variant>.yaml`` (a variant for one purpose, chosen by name)
CONFIGS_DIR = Path(__file__).resolve().parent.parent / "configs"
#: the files of a run directory (see :mod:`jaxenvs.run.runner`)
CONFIG_FILE, PROGRESS_FILE, SUMMARY_FILE = "config.yaml", "progress.csv", "summary.json"
CHECKPOINT_FILE, CURVE_FILE, VIDEO_FILE = "checkpoint.npz", "learning_curve.png", "video.mp4"


@dataclasses.dataclass(frozen=True)
class RunConfig:
    """The ``train:`` section: how the runner drives a trainer.

    Attributes:
      seed: the base seed; seed ``k`` of a multi-seed run uses ``fold_in(key(seed), k)``.
      num_seeds: independent trainings run together as one program (``vmap``-ed; one seed
        alone is traced without the seed axis, so its bits need not match the same seed's
        in a batch of seeds).
      eval_episodes: greedy-policy episodes per seed for the final evaluation.
      eval_every: also evaluate every this many chunks (0: only at the end), logged as
        ``eval_return`` in progress.csv (for time-to-threshold measurements).
      video: render ``video.mp4`` of the greedy policy at the end (when rendering works).
    """

    seed: int = 0
    num_seeds: int = 1
    eval_episodes: int = 20
    eval_every: int = 0
    video: bool = True

    def validate(self) -> None:
        require(self.seed >= 0, "seed", "must be >= 0")
        require(self.num_seeds >= 1, "num_seeds", "must be >= 1")
        require(self.eval_episodes >= 1, "eval_episodes", "must be >= 1")
        require(self.eval_every >= 0, "eval_every", "must be >= 0")


@dataclasses.dataclass(frozen=True)
class ResolvedConfig:
    """Everything a run needs, validated: env id + task config, algorithm, run settings."""

    env_id: str
    env: Any  # the task config dataclass
    algo: str
    agent: Any  # the algorithm config dataclass
    train: RunConfig

    def to_dict(self) -> dict[str, Any]:
        return {
            "algo": self.algo,
            "env": {"id": self.env_id, **config_to_dict(self.env)},
            "agent": config_to_dict(self.agent),
            "train": config_to_dict(self.train),
        }


# ------------------------------------------------------------------ algorithms & configs
def algorithm(name: str) -> tuple[type, Callable[[Env, Any], Trainer]]:
    """``(config class, make_trainer)`` of ``--algo name``; clear errors when missing."""
    if name not in ALGORITHMS:
        raise ConfigError(f"unknown algorithm {name!r}; choose from {', '.join(ALGORITHMS)}")
    entry = ALGORITHMS[name]
    try:
        module = importlib.import_module(entry.module)
    except ModuleNotFoundError as err:
        if err.name != entry.module:
            raise
        raise ConfigError(
            f"algorithm {name!r} is not available yet in this version ({entry.module} is missing)"
        ) from None
    config_cls = getattr(module, entry.config_class, None)
    make = getattr(module, entry.make_trainer, None)
    if config_cls is None or make is None:
        raise ConfigError(
            f"algorithm {name!r} is not available yet: {entry.module} lacks "
            f"{entry.config_class} or {entry.make_trainer}"
        )
    return config_cls, make


def _section(data: Mapping[str, Any], name: str, source: str) -> dict[str, Any]:
    value = data.get(name) or {}
    if not isinstance(value, dict):
        raise ConfigError(
            f"{source}: section {name!r} must be a mapping, got a {type(value).__name__}"
        )
    return dict(value)


def resolve_config(
    env_id: str | None,
    algo: str | None,
    config_file: str | Path | None = None,
    agent_overrides: Mapping[str, Any] | None = None,
    train_overrides: Mapping[str, Any] | None = None,
    source: str = "command line",
) -> ResolvedConfig:
    """Defaults <- config file <- command-line values (``None`` values are ignored).

    Without ``config_file``, the shipped ``configs/<algo>_<env_id>.yaml`` is used when it
    exists (see :func:`shipped_config`).

    Errors (unknown section or key, wrong type, impossible value) name the key and the
    file (or ``source``) they came from.
    """
    data: dict[str, Any] = {}
    if config_file is None and env_id is not None and algo is not None:
        config_file = shipped_config(algo, env_id)
    elif config_file is not None:
        config_file = locate_config(config_file)
    file_src = str(config_file) if config_file is not None else source
    if config_file is not None:
        data = load_yaml(config_file)
        unknown = sorted(set(data) - set(SECTIONS), key=str)
        if unknown:
            raise ConfigError(
                f"{file_src}: unknown section(s) {name_some(unknown)}; "
                f"valid sections: {', '.join(SECTIONS)}"
            )
    env_section = _section(data, "env", file_src)
    file_env_id = env_section.pop("id", None)
    if env_id is None:
        env_id = file_env_id
    if env_id is None:
        raise ConfigError("no env id: give ENV_ID or set env.id in the config file")
    if file_env_id is not None and file_env_id != env_id:
        raise ConfigError(f"{file_src}: the config is for env {file_env_id!r}, not {env_id!r}")
    file_algo = data.get("algo")
    if file_algo is not None and not isinstance(file_algo, str):
        raise ConfigError(f"{file_src}: key 'algo' expects a string, got {file_algo!r}")
    algo = algo or file_algo
    if algo is None:
        raise ConfigError("no algorithm: give --algo or set algo in the config file")
    task_config = registry.make_config(env_id, env_section, f"{file_src} (env)")
    config_cls, _ = algorithm(algo)
    agent = apply_overrides(config_cls(), _section(data, "agent", file_src), f"{file_src} (agent)")
    cli_agent = {k: v for k, v in (agent_overrides or {}).items() if v is not None}
    agent = apply_overrides(agent, cli_agent, source)
    run = apply_overrides(RunConfig(), _section(data, "train", file_src), f"{file_src} (train)")
    cli_train = {k: v for k, v in (train_overrides or {}).items() if v is not None}
    run = apply_overrides(run, cli_train, source)
    return ResolvedConfig(env_id, task_config, algo, agent, run)


def locate_config(name: str | Path) -> Path:
    """``name`` as a path when that file exists; else, for a bare file name, the shipped
    config of that name (``configs/<name>``, e.g. ``ppo_HexapodJoystick-v0.link.yaml``)
    when there is one; else ``name`` (whose load then reports it missing)."""
    path = Path(name)
    shipped = CONFIGS_DIR / path.name
    if not path.is_file() and path.name == str(name) and shipped.is_file():
        return shipped
    return path


def shipped_config(algo: str, env_id: str) -> Path | None:
    """The tuned config shipped for ``algo`` on ``env_id``, ``configs/<algo>_<id>.yaml``,
    used when no ``--config`` is given; ``None`` when there is none."""
    path = CONFIGS_DIR / f"{algo}_{env_id}.yaml"
    return path if path.is_file() else None


def load_run_config(run_dir: str | Path) -> ResolvedConfig:
    """The resolved config a run directory was started with."""
    path = Path(run_dir) / CONFIG_FILE
    if not path.is_file():
        raise ConfigError(f"{run_dir} is not a run directory (no {CONFIG_FILE})")
    return resolve_config(None, None, path)


def build(resolved: ResolvedConfig) -> tuple[Env, Trainer]:
    """The single env and the trainer of a resolved config."""
    env = registry.spec(resolved.env_id).factory(resolved.env)
    _, make_trainer = algorithm(resolved.algo)
    return env, make_trainer(env, resolved.agent)


def seed_keys(seed: int, num_seeds: int) -> jax.Array:
    """One training key per seed: ``fold_in(key(seed), k)``."""
    base = jax.random.key(seed)
    return jax.vmap(lambda k: jax.random.fold_in(base, k))(jnp.arange(num_seeds))


def with_physics(resolved: ResolvedConfig, physics: str | None) -> ResolvedConfig:
    """``resolved`` with its env stepped by ``physics`` (``None``: as it is)."""
    if physics is None:
        return resolved
    env = apply_overrides(resolved.env, {"physics": physics}, "--physics")
    return dataclasses.replace(resolved, env=env)


def engine_resolved(resolved: ResolvedConfig) -> ResolvedConfig:
    """``resolved`` with ``physics="auto"`` replaced by the engine it picks on this machine
    for the agent's ``num_envs`` (:func:`jaxenvs.physics.resolve_engine`).

    That is what a run's ``config.yaml`` records, so a run and its resume (or a repeat of
    it) in one process share one set of compiled programs
    (:func:`jaxenvs.run.programs.build_programs` is cached per config) and one set of
    stored ones.
    """
    if getattr(resolved.env, "physics", None) != "auto":
        return resolved
    factory = registry.spec(resolved.env_id).factory
    env = with_engine(factory, resolved.env, getattr(resolved.agent, "num_envs", None))
    if env.physics == "auto":  # a factory function: build the env to see what it picked
        env = dataclasses.replace(env, physics=factory(env).physics)
    return dataclasses.replace(resolved, env=env)
