"""The training runner behind ``jaxenvs train`` / ``eval`` / ``compare``; algorithm-agnostic.

An algorithm is a module in :data:`ALGORITHMS` exposing a frozen config dataclass (with
at least ``num_envs`` and ``total_steps`` fields, which ``--num-envs`` / ``--total-steps``
override) and ``make_trainer(env, config) -> Trainer`` (see :mod:`jaxenvs.agents.base`).

A config file is YAML with separate sections, all optional::

    algo: qlearning            # qlearning | sarsa | ppo
    env:   {id: CartPole-v0, episode_length: 500}   # id + task config overrides
    agent: {alpha: 0.1, ...}   # the algorithm's config fields
    train: {seed: 0, num_seeds: 1, ...}              # RunConfig fields

A run directory holds ``config.yaml`` (fully resolved: every field of every section),
``progress.csv`` (one row per chunk and seed, with wall and process-CPU seconds),
``checkpoint.npz`` (written atomically after every chunk), ``summary.json``,
``learning_curve.png`` and, when rendering works, ``video.mp4``. The run itself:
``vmap(init)`` over ``num_seeds`` keys, then a Python loop over chunks of one jitted
``vmap(chunk)``; a chunk is a pure function of the runner state,
so resuming from the checkpoint after chunk ``i`` gives the same final state as a run
that never stopped.
"""

from __future__ import annotations

import concurrent.futures
import csv
import dataclasses
import functools
import importlib
import json
import math
import signal
import sys
import threading
import time
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
import yaml

from jaxenvs import compile_cache, files, machine, program_cache, registry, sharding
from jaxenvs.agents import checkpoint
from jaxenvs.agents.base import CHUNK_METRICS, Trainer
from jaxenvs.config import ConfigError, apply_overrides, config_to_dict, load_yaml, require
from jaxenvs.core import Env, batch_devices, cpu_auto, resolve_physics

PyTree = Any


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
CONFIG_FILE, PROGRESS_FILE, SUMMARY_FILE = "config.yaml", "progress.csv", "summary.json"
CHECKPOINT_FILE, CURVE_FILE, VIDEO_FILE = "checkpoint.npz", "learning_curve.png", "video.mp4"
#: the end-of-run video: frames per simulated second (at most) and (width, height)
VIDEO_FPS, VIDEO_SIZE = 25.0, (640, 480)


@dataclasses.dataclass(frozen=True)
class RunConfig:
    """The ``train:`` section: how the runner drives a trainer.

    Attributes:
      seed: the base seed; seed ``k`` of a multi-seed run uses ``fold_in(key(seed), k)``.
      num_seeds: independent trainings vmapped together.
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
        raise ConfigError(f"{source}: section {name!r} must be a mapping, got {value!r}")
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
    file_src = str(config_file) if config_file is not None else source
    if config_file is not None:
        data = load_yaml(config_file)
        unknown = sorted(set(data) - set(SECTIONS))
        if unknown:
            raise ConfigError(
                f"{file_src}: unknown section(s) {', '.join(map(repr, unknown))}; "
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


#: shipped configs whose names predate the ``<algo>_<id>.yaml`` rule (the course's names)
SHIPPED_CONFIGS = {
    ("qlearning", "CartPole-v0"): "cartpole_qlearn.yaml",
    ("sarsa", "CartPole-v0"): "cartpole_sarsa.yaml",
    ("qlearning", "CartpoleStayUp-v0"): "cartpole_stayup_qlearn.yaml",
    ("sarsa", "CartpoleStayUp-v0"): "cartpole_stayup_sarsa.yaml",
}


def shipped_config(algo: str, env_id: str) -> Path | None:
    """The tuned config shipped for ``algo`` on ``env_id`` (``configs/<algo>_<id>.yaml``
    or the entry in :data:`SHIPPED_CONFIGS`), used when no ``--config`` is given; ``None``
    when there is none."""
    name = SHIPPED_CONFIGS.get((algo, env_id), f"{algo}_{env_id}.yaml")
    path = Path(__file__).resolve().parent.parent / "configs" / name
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


# ------------------------------------------------------------------------- evaluation
def make_evaluator(
    env: Env, act: Callable[[PyTree, jax.Array, jax.Array], jax.Array], episodes: int
) -> Callable[[PyTree, jax.Array], tuple[jax.Array, Any, jax.Array]]:
    """``evaluate(params, key) -> (returns (episodes,), trajectory, length)``.

    Greedy episodes from fresh random starts, each until it terminates or truncates (no
    auto-reset). ``trajectory`` is the first episode's States stacked over time (the
    reset state first, ``episode_length + 1`` entries) and ``length`` its length, so
    a video needs no second compile.
    """

    def evaluate(params: PyTree, key: jax.Array) -> tuple[jax.Array, Any, jax.Array]:
        reset_key, act_key = jax.random.split(key)
        first = jax.vmap(env.reset)(jax.random.split(reset_key, episodes))

        def body(carry: tuple[Any, ...], k: jax.Array) -> tuple[tuple[Any, ...], Any]:
            state, done, ret, length = carry
            keys = jax.random.split(k, episodes)
            action = jax.vmap(act, in_axes=(None, 0, 0))(params, state.obs, keys)
            nxt = jax.vmap(env.step)(state, action)
            ret = ret + jnp.where(done, 0.0, nxt.reward)
            length = length + (~done).astype(jnp.int32)
            return (nxt, done | nxt.done, ret, length), jax.tree.map(lambda x: x[0], nxt)

        carry = (
            first,
            jnp.zeros(episodes, bool),
            jnp.zeros(episodes, jnp.float32),
            jnp.zeros(episodes, jnp.int32),
        )
        keys = jax.random.split(act_key, env.episode_length)
        (_, _, ret, length), traj = jax.lax.scan(body, carry, keys)
        head = jax.tree.map(lambda x: x[0], first)
        traj = jax.tree.map(lambda a, b: jnp.concatenate([a[None], b]), head, traj)
        traj = traj.replace(key=jax.random.key_data(traj.key))  # host-convertible
        return ret, traj, length[0]

    return evaluate


def eval_key(seed: int) -> jax.Array:
    """The key of the final evaluation: independent of every training key."""
    return jax.random.fold_in(jax.random.key(seed), 2**31 - 1)


# ----------------------------------------------------------------------- progress I/O
def _metric_columns(metric_shapes: Mapping[str, Any]) -> list[str]:
    extra = sorted(
        k for k, v in metric_shapes.items() if k not in CHUNK_METRICS and len(v.shape) == 1
    )
    return ["chunk", "seed", *CHUNK_METRICS, *extra, "eval_return", "wall_seconds", "cpu_seconds"]


def _read_progress(path: Path) -> list[dict[str, str]]:
    if not path.is_file():
        return []
    with path.open(newline="") as f:
        return list(csv.DictReader(f))


def _write_progress(path: Path, columns: list[str], rows: list[dict[str, Any]]) -> None:
    with files.atomic_path(path) as tmp, tmp.open("w", newline="") as f:
        writer = csv.DictWriter(f, columns, extrasaction="ignore")
        writer.writeheader()
        writer.writerows(rows)


def _fmt(x: Any) -> str:
    x = np.asarray(x).item()
    if isinstance(x, float):
        return "nan" if math.isnan(x) else f"{x:.6g}"
    return str(x)


def _write_json(path: Path, data: Mapping[str, Any]) -> None:
    files.write_text(path, json.dumps(data, indent=2, allow_nan=True) + "\n")


# ------------------------------------------------------------------------ the runner
class _Progress:
    """tqdm bar over env steps, or nothing when quiet / not a terminal."""

    def __init__(self, total: int, initial: int, quiet: bool, desc: str) -> None:
        self.bar = None
        if not quiet and sys.stderr.isatty():
            from tqdm import tqdm

            self.bar = tqdm(total=total, initial=initial, desc=desc, unit="step", smoothing=0.3)

    def update(self, steps: int, postfix: dict[str, str]) -> None:
        if self.bar is not None:
            self.bar.update(steps)
            self.bar.set_postfix(postfix, refresh=True)

    def close(self) -> None:
        if self.bar is not None:
            self.bar.close()


def _rate_key(metrics: Mapping[str, Any]) -> str | None:
    for key in ("epsilon", "learning_rate", "lr"):
        if key in metrics:
            return key
    return None


_COMPILER = concurrent.futures.ThreadPoolExecutor(1, thread_name_prefix="jaxenvs-compile")


@dataclasses.dataclass(frozen=True)
class _Programs:
    env: Env
    trainer: Trainer
    init_fn: Any
    chunk_fn: Any
    eval_future: concurrent.futures.Future

    def evaluate(self, params: PyTree, key: jax.Array) -> Any:
        # compiled for one device; a run over several holds its params replicated
        params = jax.device_put(params, jax.local_devices()[0])
        return self.eval_future.result()(params, key)


@functools.lru_cache(maxsize=4)
def _programs(resolved: ResolvedConfig, devices: int | None = None) -> _Programs:
    """Env, trainer, the jitted ``vmap``s of init and chunk, and the evaluator.

    The evaluator is compiled ahead of time on a background thread while the caller
    compiles and runs the training chunks (XLA compiles one program per core, so on a
    small machine this hides most of the evaluator's compile). Cached per config, so a
    resume or a second run in the same process reuses the compiled programs. Over more
    than one device (``devices``; ``None`` = all), init and chunk split the env batch
    over a mesh of them (:func:`jaxenvs.sharding.shard_trainer_fns`). On one device,
    with the compile cache on, init, chunk and evaluator are stored traced and loaded on
    later runs (:func:`_program_store`), so a warm start skips most tracing as well as
    compiling.
    """
    env, trainer = build(resolved)
    if devices is None and jax.process_count() == 1:
        # all local devices that num_envs divides over; one under the C engine, whose
        # own threads spread the batch
        devices = batch_devices(resolved.agent.num_envs, None, env.physics)
    mesh = sharding.make_mesh(devices)
    init_fn: Any = None
    chunk_fn: Any = None
    if mesh.size > 1:
        init_fn, chunk_fn = sharding.shard_trainer_fns(
            trainer, mesh, resolved.agent.num_envs, num_seeds=resolved.train.num_seeds
        )
    evaluator = make_evaluator(env, trainer.act, resolved.train.eval_episodes)
    keys = seed_keys(resolved.train.seed, resolved.train.num_seeds)
    key_shape = jax.eval_shape(lambda: eval_key(0))
    store = _program_store(resolved, env, trainer) if mesh.size == 1 else None
    if store is not None:
        # the training state's structure, which the stored programs' outputs refer to
        # (~0.5 s of tracing init). init runs through the store too: a state made by a
        # plain jit would reach the chunk with other input shardings and compile it twice
        template = jax.eval_shape(jax.vmap(trainer.init), keys)
        init_fn = store(jax.vmap(trainer.init), (keys,), "init", (template,)).call
        chunk_fn = store(jax.vmap(trainer.chunk), (template,), "chunk", (template,)).call
        params_shape = jax.eval_shape(jax.vmap(trainer.policy_params), template)
        env_state = jax.eval_shape(env.reset, jax.random.key(0))  # the trajectory's structure

        def compile_evaluate() -> Any:
            evaluate = jax.vmap(evaluator, in_axes=(0, None))
            program = store(evaluate, (params_shape, key_shape), "eval", (env_state,))
            return program.jitted.lower(params_shape, key_shape).compile()

        return _Programs(env, trainer, init_fn, chunk_fn, _COMPILER.submit(compile_evaluate))
    if mesh.size == 1:
        init_fn = jax.jit(jax.vmap(trainer.init))
        chunk_fn = jax.jit(jax.vmap(trainer.chunk))
    evaluate = jax.jit(jax.vmap(evaluator, in_axes=(0, None)))
    params_shape = jax.eval_shape(jax.vmap(trainer.policy_params), jax.eval_shape(init_fn, keys))
    future = _COMPILER.submit(lambda: evaluate.lower(params_shape, key_shape).compile())
    return _Programs(env, trainer, init_fn, chunk_fn, future)


#: modules whose tasks and trainers may have their programs stored: the key covers the
#: package's own files only (see :mod:`jaxenvs.program_cache`).
_STORE_MODULES: tuple[str, ...] = ("jaxenvs.",)


def _program_store(
    resolved: ResolvedConfig, env: Env, trainer: Trainer
) -> Callable[..., program_cache.Program] | None:
    """Loads/stores traced programs next to the compile cache (``None``: not used).

    Used only while the compile cache is on and for tasks and trainers defined in this
    package, whose code the stored programs' keys cover (see :mod:`jaxenvs.program_cache`).
    """
    cache = compile_cache.active()
    factory = registry.spec(resolved.env_id).factory
    owners = (type(env).__module__, type(trainer).__module__, getattr(factory, "__module__", ""))
    if cache is None or not all(str(m).startswith(_STORE_MODULES) for m in owners):
        return None
    if env.physics != "mjx":  # a stored (exported) program cannot carry a host callback
        return None
    settings = resolved.to_dict()
    settings["train"] = {k: v for k, v in settings["train"].items() if k != "seed"}

    def store(
        fn: Callable[..., Any], args: tuple[Any, ...], name: str, known: tuple[Any, ...]
    ) -> program_cache.Program:
        return program_cache.load_or_export(
            fn,
            args,
            name=f"{resolved.algo}-{resolved.env_id}-{name}",
            config=settings,
            directory=cache / program_cache.SUBDIR,
            known=known,
        )

    return store


class RunState(NamedTuple):
    """What a run has committed after ``chunk`` chunks: the runner state, the rows of
    progress.csv, the longest episode lengths per seed (``top``) and whether the run is
    over. The checkpoint on disk always holds the last committed one."""

    state: PyTree
    rows: list[dict[str, Any]]
    top: np.ndarray
    finished: bool
    chunk: int


@dataclasses.dataclass(frozen=True)
class _Clock:
    """Wall and process-CPU seconds of a run, those of earlier calls (resume) included."""

    t0: float
    cpu0: float
    wall_before: float = 0.0
    cpu_before: float = 0.0

    def wall(self) -> float:
        return self.wall_before + time.perf_counter() - self.t0

    def cpu(self) -> float:
        return self.cpu_before + time.process_time() - self.cpu0


@dataclasses.dataclass(frozen=True)
class _Run:
    """What every step of :func:`train` needs besides the :class:`RunState`."""

    resolved: ResolvedConfig
    out: Path
    programs: _Programs
    params_fn: Callable[[PyTree], PyTree]
    keys: jax.Array
    template: PyTree  # the runner state's structure (``eval_shape``)
    columns: list[str]  # of progress.csv
    say: Callable[[str], None]

    @property
    def trainer(self) -> Trainer:
        return self.programs.trainer

    @property
    def num_seeds(self) -> int:
        return self.resolved.train.num_seeds


def _engine_resolved(resolved: ResolvedConfig) -> ResolvedConfig:
    """``resolved`` with ``physics="auto"`` replaced by the engine it picks on this machine.

    That is what a run's ``config.yaml`` records, so a run and its resume (or a repeat of
    it) in one process share one set of compiled programs (:func:`_programs` is cached
    per config) and one set of stored ones.
    """
    if getattr(resolved.env, "physics", None) != "auto":
        return resolved
    factory = registry.spec(resolved.env_id).factory
    cpu_default = getattr(factory, "cpu_physics", None) if isinstance(factory, type) else None
    by_batch = cpu_auto(factory, getattr(resolved.train, "num_envs", None))
    if by_batch is not None:
        physics = by_batch
    elif isinstance(cpu_default, str):
        physics = resolve_physics("auto", cpu_default)
    else:  # a factory function: build the env to see what it picked
        physics = factory(resolved.env).physics
    return dataclasses.replace(resolved, env=dataclasses.replace(resolved.env, physics=physics))


def _prepare(
    resolved: ResolvedConfig, out: Path, devices: int | None, say: Callable[[str], None]
) -> _Run:
    resolved = _engine_resolved(resolved)
    programs = _programs(resolved, devices)
    say(machine.describe(programs.env))
    keys = seed_keys(resolved.train.seed, resolved.train.num_seeds)
    params_fn = jax.vmap(programs.trainer.policy_params)
    template = jax.eval_shape(programs.init_fn, keys)
    metric_shapes = jax.eval_shape(programs.chunk_fn, template)[1]
    columns = _metric_columns(metric_shapes)
    return _Run(resolved, out, programs, params_fn, keys, template, columns, say)


def _save_checkpoint(run: _Run, clock: _Clock, rs: RunState) -> None:
    checkpoint.save(
        run.out / CHECKPOINT_FILE,
        rs.state,
        {
            "chunk": rs.chunk,
            "wall_seconds": clock.wall(),
            "cpu_seconds": clock.cpu(),
            "top_lengths": rs.top.tolist(),
            "finished": rs.finished,
            **_identity(run),
        },
    )


def _identity(run: _Run) -> dict[str, Any]:
    """What a checkpoint must match to be resumed by ``run``: env id, algorithm and the
    config that config.yaml records (``train.video`` aside, which a resume may change)."""
    record = dataclasses.replace(run.resolved, env=run.programs.env.config).to_dict()
    record["train"].pop("video", None)
    return {"env_id": run.resolved.env_id, "algo": run.resolved.algo, "config": record}


def _start(run: _Run, clock: _Clock) -> RunState:
    """A fresh run: config.yaml, the initial state and its checkpoint (chunk 0)."""
    # the env's config holds the engine "auto" resolved to (``physics``)
    record = dataclasses.replace(run.resolved, env=run.programs.env.config).to_dict()
    files.write_text(run.out / CONFIG_FILE, yaml.safe_dump(record, sort_keys=False))
    state = run.programs.init_fn(run.keys)
    rs = RunState(state, [], np.full((run.num_seeds, 0), -1.0, np.float32), False, 0)
    _save_checkpoint(run, clock, rs)
    return rs


def _resume(run: _Run, clock: _Clock) -> tuple[RunState, _Clock]:
    """The committed state of the checkpoint, progress.csv's rows up to it, and the clock
    counting the seconds already spent."""
    state, meta = checkpoint.load(run.out / CHECKPOINT_FILE, run.template)
    expected = _identity(run)
    checkpoint.check_matches(
        run.out / CHECKPOINT_FILE, {k: meta.get(k) for k in expected}, expected
    )
    start = int(meta["chunk"])
    clock = dataclasses.replace(
        clock,
        wall_before=float(meta["wall_seconds"]),
        cpu_before=float(meta.get("cpu_seconds", 0.0)),
    )
    top = np.asarray(meta["top_lengths"], np.float32).reshape(run.num_seeds, -1)
    rows = [r for r in _read_progress(run.out / PROGRESS_FILE) if int(r["chunk"]) < start]
    finished = bool(meta.get("finished", False))
    run.say(f"resuming {run.out} at chunk {start}/{run.trainer.num_chunks}")
    return RunState(state, rows, top, finished, start), clock


def _chunk_rows(
    run: _Run, clock: _Clock, chunk: int, metrics: Mapping[str, Any], eval_mean: float
) -> list[dict[str, Any]]:
    """progress.csv's rows of one chunk, one per seed."""
    wall, cpu = clock.wall(), clock.cpu()
    rows = []
    for k in range(run.num_seeds):
        row: dict[str, Any] = {c: _fmt(metrics[c][k]) for c in run.columns if c in metrics}
        row.update(chunk=chunk, seed=k, wall_seconds=f"{wall:.3f}")
        row["cpu_seconds"] = f"{cpu:.3f}"
        row["eval_return"] = _fmt(eval_mean)
        rows.append(row)
    return rows


def _top_lengths(top: np.ndarray, metrics: Mapping[str, Any]) -> np.ndarray:
    """The (at most 100) longest episodes per seed, with those of a new chunk."""
    if "top_lengths" not in metrics:
        return top
    both = np.concatenate([top, np.asarray(metrics["top_lengths"], np.float32)], 1)
    return -np.sort(-both, axis=1)[:, : min(100, both.shape[1])]


def _run_chunk(run: _Run, clock: _Clock, rs: RunState) -> tuple[RunState, Any, float]:
    """One chunk as a transaction: compute the next :class:`RunState`, write progress.csv
    and the checkpoint, and only then hand it back (the commit). Returns it with the
    chunk's metrics and its compute seconds."""
    train_cfg, num_chunks = run.resolved.train, run.trainer.num_chunks
    last = time.perf_counter()
    state, metrics = run.programs.chunk_fn(rs.state)
    metrics = jax.device_get(metrics)
    seconds = time.perf_counter() - last
    eval_mean = math.nan
    if train_cfg.eval_every and (rs.chunk + 1) % train_cfg.eval_every == 0:
        returns, _, _ = run.programs.evaluate(run.params_fn(state), eval_key(train_cfg.seed))
        eval_mean = float(np.mean(returns))
    rows = rs.rows + _chunk_rows(run, clock, rs.chunk, metrics, eval_mean)
    finished = rs.chunk + 1 >= num_chunks
    if "active_envs" in metrics and not np.any(np.asarray(metrics["active_envs"]) > 0):
        finished = True
    nxt = RunState(state, rows, _top_lengths(rs.top, metrics), finished, rs.chunk + 1)
    _write_progress(run.out / PROGRESS_FILE, run.columns, nxt.rows)
    _save_checkpoint(run, clock, nxt)
    return nxt, metrics, seconds


def _progress_postfix(metrics: Mapping[str, Any], seconds: float, steps: int) -> dict[str, str]:
    """The progress bar's figures of a chunk of ``steps`` env steps (all seeds)."""
    postfix = {
        "ep/s": f"{float(np.sum(metrics['episodes_in_chunk'])) / seconds:.0f}",
        "steps/s": f"{steps / seconds:.3g}",
        "return": f"{np.nanmean(metrics['mean_return']):.1f}"
        if np.any(np.isfinite(metrics["mean_return"]))
        else "-",
    }
    rk = _rate_key(metrics)
    if rk is not None:
        postfix[rk] = f"{float(np.mean(metrics[rk])):.3g}"
    return postfix


def _finish(run: _Run, clock: _Clock, rs: RunState, interrupted: bool) -> dict[str, Any]:
    """The final evaluation, summary.json, the learning curve and (unless interrupted)
    the video of the best seed; returns the summary."""
    train_cfg, out = run.resolved.train, run.out
    wall = clock.wall()
    result = run.programs.evaluate(run.params_fn(rs.state), eval_key(train_cfg.seed))
    returns, trajectory, lengths = jax.device_get(result)
    returns = np.asarray(returns)
    summary = _summary(
        rs.rows, returns, rs.top, wall, rs.chunk, run.trainer.num_chunks, rs.finished
    )
    summary.update(env_id=run.resolved.env_id, algo=run.resolved.algo, interrupted=interrupted)
    summary["physics"] = run.programs.env.physics
    # process CPU time (all threads): on a shared, loaded machine a steadier figure than wall
    summary["cpu_seconds"] = round(clock.cpu(), 3)
    _write_json(out / SUMMARY_FILE, summary)
    try:
        plot_curves([out], out / CURVE_FILE)
    except Exception as err:  # noqa: BLE001 - a plot must never lose the results
        run.say(f"no learning curve: {err}")
    if train_cfg.video and not interrupted:
        best = int(np.argmax(returns.mean(axis=1)))
        traj = jax.tree.map(lambda x: x[best], trajectory)
        write_policy_video(run.programs.env, traj, int(lengths[best]), out / VIDEO_FILE, run.say)
    return summary


def train(
    resolved: ResolvedConfig,
    out_dir: str | Path,
    *,
    resume: bool = False,
    quiet: bool = False,
    max_chunks: int | None = None,
    log: Callable[[str], None] | None = None,
    devices: int | None = None,
) -> dict[str, Any]:
    """Train (or continue) a run in ``out_dir``; returns the summary it writes.

    Args:
      resolved: the config (for ``resume``, :func:`load_run_config` of ``out_dir``).
      out_dir: the run directory (created).
      resume: continue from ``out_dir/checkpoint.npz``.
      quiet: no progress bar (it is also off when stderr is not a terminal).
      max_chunks: stop after this many chunks in THIS call (as if interrupted there;
        the run can be resumed); ``None`` runs to the end.
      log: where one-line notices go (default: stderr unless quiet).
      devices: split each seed's env batch over the first N devices (``None``: all);
        ``num_envs`` must divide evenly.

    Ctrl-C waits for the chunk in flight (a compiled program cannot be stopped part
    way), commits it (progress.csv, checkpoint), writes the results so far, says how to
    resume and raises ``KeyboardInterrupt``. A second Ctrl-C stops at once, discarding
    the chunk in flight: the checkpoint on disk stays the last committed chunk's.
    """
    clock = _Clock(time.perf_counter(), time.process_time())
    say = log or ((lambda m: None) if quiet else (lambda m: print(m, file=sys.stderr)))
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    run = _prepare(resolved, out, devices, say)
    if resume:
        rs, clock = _resume(run, clock)
    else:
        rs = _start(run, clock)
    num_chunks, steps = run.trainer.num_chunks, run.trainer.steps_per_chunk
    stop = num_chunks if max_chunks is None else min(num_chunks, rs.chunk + max_chunks)
    bar = _Progress(
        num_chunks * steps, rs.chunk * steps, quiet, f"{resolved.algo} {resolved.env_id}"
    )
    interrupted = False
    # A first Ctrl-C only asks to stop after the running chunk is committed. A second
    # one (KeyboardInterrupt inside _run_chunk) discards the chunk in flight: ``rs``
    # stays the previous chunk's, which is exactly what the checkpoint on disk holds.
    try:
        with _StopRequest(say) as stop_request:
            while rs.chunk < stop and not rs.finished and not stop_request.asked:
                rs, metrics, seconds = _run_chunk(run, clock, rs)
                bar.update(steps, _progress_postfix(metrics, seconds, steps * run.num_seeds))
            interrupted = stop_request.asked
    except KeyboardInterrupt:
        interrupted = True
        _write_progress(out / PROGRESS_FILE, run.columns, rs.rows)
    finally:
        bar.close()
    if interrupted:
        say(
            f"interrupted: results and checkpoint are of chunk {rs.chunk}/{num_chunks}; "
            f"continue with: jaxenvs train --resume {out}"
        )
    summary = _finish(run, clock, rs, interrupted)
    if interrupted:
        raise KeyboardInterrupt
    return summary


class _StopRequest:
    """While entered (in the main thread), the first SIGINT sets ``asked`` instead of
    raising, so the loop can commit the running chunk and stop; a second one raises
    ``KeyboardInterrupt`` as usual. Elsewhere it does nothing."""

    def __init__(self, say: Callable[[str], None]) -> None:
        self.asked = False
        self._say = say
        self._previous: Any = None

    def _handle(self, signum: int, frame: Any) -> None:
        if self.asked:
            raise KeyboardInterrupt
        self.asked = True
        self._say("stopping after the running chunk is saved (Ctrl-C again: stop now)")

    def __enter__(self) -> _StopRequest:
        if threading.current_thread() is threading.main_thread():
            self._previous = signal.signal(signal.SIGINT, self._handle)
        return self

    def __exit__(self, *exc: object) -> None:
        if self._previous is not None:
            signal.signal(signal.SIGINT, self._previous)


def _summary(
    rows: list[dict[str, Any]],
    eval_returns: np.ndarray,
    top: np.ndarray,
    wall: float,
    chunks: int,
    num_chunks: int,
    finished: bool,
) -> dict[str, Any]:
    num_seeds = eval_returns.shape[0]
    per_seed_steps, per_seed_eps, overall = [], [], []
    for k in range(num_seeds):
        mine = [r for r in rows if int(r["seed"]) == k]
        steps = int(float(mine[-1]["env_steps"])) if mine else 0
        eps = int(float(mine[-1]["episodes"])) if mine else 0
        total_len = sum(
            float(r["mean_length"]) * float(r["episodes_in_chunk"])
            for r in mine
            if r["mean_length"] not in ("nan", "") and float(r["episodes_in_chunk"]) > 0
        )
        per_seed_steps.append(steps)
        per_seed_eps.append(eps)
        overall.append(total_len / eps if eps else math.nan)
    best100 = [float(np.mean(t[t >= 0][:100])) if np.any(t >= 0) else math.nan for t in top]
    return {
        "eval_mean_return": float(eval_returns.mean()),
        "eval_std_return": float(eval_returns.std()),
        "eval_mean_return_per_seed": eval_returns.mean(axis=1).tolist(),
        "eval_episodes": int(eval_returns.size),
        "env_steps": int(sum(per_seed_steps)),
        "env_steps_per_seed": per_seed_steps,
        "episodes": int(sum(per_seed_eps)),
        "wall_seconds": round(wall, 3),
        "overall_score": float(np.nanmean(overall)) if num_seeds else math.nan,
        "overall_score_per_seed": overall,
        "best_100_score": float(np.nanmean(best100)) if top.size else None,
        "best_100_score_per_seed": best100 if top.size else None,
        "chunks": chunks,
        "num_chunks": num_chunks,
        "finished": finished,
        "num_seeds": num_seeds,
    }


def write_policy_video(
    env: Env, trajectory: Any, length: int, path: Path, say: Callable[[str], None]
) -> Path | None:
    """Render one episode (stacked States, reset state first) with :mod:`jaxenvs.render`.

    Rendering is optional: when :mod:`jaxenvs.render` is missing or fails (no GL backend,
    no ffmpeg), ``say`` gets a one-line notice and ``None`` is returned.
    """
    try:
        render = importlib.import_module("jaxenvs.render")
    except ImportError as err:
        say(f"no video: rendering is not available ({err})")
        return None
    try:
        # at most VIDEO_FPS frames a second of simulated time
        stride = max(1, round(1.0 / (env.control_dt * VIDEO_FPS)))
        states = jax.tree.map(lambda x: np.asarray(x)[: length + 1 : stride], trajectory)
        width, height = VIDEO_SIZE
        frames = render.render_frames(env, states, width=width, height=height)
        render.write_video(frames, path, fps=1.0 / (env.control_dt * stride))
    except Exception as err:  # noqa: BLE001 - the video is optional
        say(f"no video: {str(err).splitlines()[0] if str(err) else type(err).__name__}")
        return None
    return path


# ------------------------------------------------------------------ using a finished run
def with_physics(resolved: ResolvedConfig, physics: str | None) -> ResolvedConfig:
    """``resolved`` with its env stepped by ``physics`` (``None``: as it is)."""
    if physics is None:
        return resolved
    env = apply_overrides(resolved.env, {"physics": physics}, "--physics")
    return dataclasses.replace(resolved, env=env)


def restore(
    run_dir: str | Path, physics: str | None = None
) -> tuple[ResolvedConfig, Env, Trainer, PyTree]:
    """Config, env, trainer and the (seed-batched) runner state of a run directory;
    ``physics`` steps the env with another engine than the run's (cross-engine eval)."""
    resolved = with_physics(load_run_config(run_dir), physics)
    env, trainer = build(resolved)
    keys = seed_keys(resolved.train.seed, resolved.train.num_seeds)
    template = jax.eval_shape(jax.vmap(trainer.init), keys)
    path = Path(run_dir) / CHECKPOINT_FILE
    state, meta = checkpoint.load(path, template)
    expected = {"env_id": resolved.env_id, "algo": resolved.algo}
    checkpoint.check_matches(path, {k: meta.get(k) for k in expected}, expected)
    return resolved, env, trainer, state


def _best_seed(run_dir: Path, num_seeds: int) -> int:
    try:
        per_seed = json.loads((run_dir / SUMMARY_FILE).read_text())["eval_mean_return_per_seed"]
        return int(np.argmax(per_seed)) if len(per_seed) == num_seeds else 0
    except (OSError, ValueError, KeyError):
        return 0


def load_policy(
    run_dir: str | Path, physics: str | None = None
) -> tuple[str, Env, Callable[[jax.Array, jax.Array], jax.Array]]:
    """``(env_id, env, act_fn)`` of a run: ``act_fn(obs, key) -> action`` for ONE obs.

    The policy is the greedy policy of the seed with the best final evaluation (seed 0
    when there is no summary). ``act_fn`` is jittable and vmappable. ``physics`` builds
    the env with another engine than the run's.
    """
    resolved, env, trainer, state = restore(run_dir, physics)
    seed = _best_seed(Path(run_dir), resolved.train.num_seeds)
    params = jax.tree.map(lambda x: x[seed], jax.vmap(trainer.policy_params)(state))

    def act_fn(obs: jax.Array, key: jax.Array) -> jax.Array:
        return trainer.act(params, obs, key)

    return resolved.env_id, env, act_fn


def evaluate_run(
    run_dir: str | Path,
    episodes: int,
    seed: int | None = None,
    video: str | Path | None = None,
    physics: str | None = None,
) -> dict[str, Any]:
    """Greedy evaluation of every seed of a run from its checkpoint (and a video);
    ``physics`` evaluates under another engine than the one it trained on."""
    resolved, env, trainer, state = restore(run_dir, physics)
    k = resolved.train.seed + 1 if seed is None else seed
    params = jax.vmap(trainer.policy_params)(state)
    evaluate = jax.jit(jax.vmap(make_evaluator(env, trainer.act, episodes), in_axes=(0, None)))
    returns, trajectory, lengths = jax.device_get(evaluate(params, eval_key(k)))
    returns = np.asarray(returns)
    result = {
        "env_id": resolved.env_id,
        "algo": resolved.algo,
        "physics": env.physics,
        "episodes": int(returns.size),
        "mean_return": float(returns.mean()),
        "std_return": float(returns.std()),
        "mean_return_per_seed": returns.mean(axis=1).tolist(),
    }
    if video is not None:
        best = int(np.argmax(returns.mean(axis=1)))
        traj = jax.tree.map(lambda x: x[best], trajectory)
        msgs: list[str] = []
        written = write_policy_video(env, traj, int(lengths[best]), Path(video), msgs.append)
        result["video"] = str(written) if written else None
        if msgs:
            result["video_error"] = msgs[0]
    return result


# ------------------------------------------------------------------------------ plots
def learning_curve(run_dir: str | Path) -> tuple[np.ndarray, np.ndarray]:
    """``(env_steps per chunk, mean_return (chunks, seeds))`` from a run's progress.csv."""
    rows = _read_progress(Path(run_dir) / PROGRESS_FILE)
    if not rows:
        raise ValueError(f"{run_dir}: no progress recorded yet ({PROGRESS_FILE})")
    chunks = sorted({int(r["chunk"]) for r in rows})
    seeds = sorted({int(r["seed"]) for r in rows})
    index = {(int(r["chunk"]), int(r["seed"])): r for r in rows}
    steps = np.zeros(len(chunks))
    ret = np.full((len(chunks), len(seeds)), np.nan)
    for i, c in enumerate(chunks):
        for j, s in enumerate(seeds):
            r = index.get((c, s))
            if r is None:
                continue
            ret[i, j] = float(r["mean_return"])
            steps[i] = max(steps[i], float(r["env_steps"]))
    return steps, ret


def plot_curves(run_dirs: list[Path], out: str | Path, labels: list[str] | None = None) -> Path:
    """Return vs env steps of each run: every seed thin, the mean bold, min-max shaded."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(7, 4.5))
    for i, run_dir in enumerate(run_dirs):
        steps, ret = learning_curve(run_dir)
        label = labels[i] if labels else _run_label(Path(run_dir))
        color = f"C{i}"
        if ret.shape[1] > 1:
            ax.plot(steps, ret, color=color, alpha=0.25, linewidth=0.8)
            with np.errstate(all="ignore"):
                lo, hi = np.nanmin(ret, axis=1), np.nanmax(ret, axis=1)
            ax.fill_between(steps, lo, hi, color=color, alpha=0.15)
        with np.errstate(all="ignore"):
            mean = np.nanmean(ret, axis=1) if ret.shape[1] else ret
        ax.plot(steps, mean, color=color, linewidth=2, label=f"{label} ({_seeds(ret.shape[1])})")
    ax.set_xlabel("env steps")
    ax.set_ylabel("mean episode return (per chunk)")
    ax.grid(alpha=0.3)
    ax.legend(loc="best", fontsize=8)
    fig.tight_layout()
    out = Path(out)
    with files.atomic_path(out) as tmp:
        fig.savefig(tmp, dpi=100)
    plt.close(fig)
    return out


def _seeds(n: int) -> str:
    return f"{n} seed" if n == 1 else f"{n} seeds"


def _run_label(run_dir: Path) -> str:
    try:
        cfg = yaml.safe_load((run_dir / CONFIG_FILE).read_text())
        return f"{cfg['algo']} {cfg['env']['id']} ({run_dir.name})"
    except (OSError, yaml.YAMLError, KeyError, TypeError):
        return run_dir.name
