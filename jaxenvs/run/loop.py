"""The run loop: a run's chunks as transactions, its checkpoints, resume and Ctrl-C.

:func:`train` is ``init`` over ``num_seeds`` keys, then a Python loop over chunks of the
compiled chunk over the seeds (:mod:`jaxenvs.run.programs`: a ``vmap`` for several seeds,
one seed traced without it; on an accelerator a PPO chunk runs as its stages' programs,
whose compiles start before ``init`` runs). Each chunk commits
progress.csv and the checkpoint before the loop moves on, and a chunk is a pure function
of the runner state, so resuming from the checkpoint after chunk ``i`` gives the same
final state as a run that never stopped. A checkpoint records what it is a run of
(:func:`_identity`); a resume refuses one that does not match. A run holds its directory
(:func:`jaxenvs.files.claim_directory`) from before its first file to its last, so two
runs never mix their files in one.
"""

from __future__ import annotations

import dataclasses
import math
import os
import signal
import sys
import threading
import time
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any, NamedTuple

import jax
import numpy as np
import yaml

from jaxenvs import files, machine
from jaxenvs.agents.base import Trainer
from jaxenvs.run import checkpoint
from jaxenvs.run.evaluation import eval_key
from jaxenvs.run.placement import resolve_scaling
from jaxenvs.run.programs import Programs, build_programs
from jaxenvs.run.results import (
    LEVEL,
    ProgressBar,
    format_value,
    metric_columns,
    plot_curves,
    preload_plotting,
    progress_postfix,
    read_progress,
    summarize,
    task_level,
    write_json,
    write_progress,
)
from jaxenvs.run.run_config import (
    CHECKPOINT_FILE,
    CONFIG_FILE,
    CURVE_FILE,
    PROGRESS_FILE,
    SUMMARY_FILE,
    VIDEO_FILE,
    ResolvedConfig,
    engine_resolved,
    seed_keys,
)
from jaxenvs.run.video import PolicyVideo

PyTree = Any

#: the files a run writes (atomically) in its directory
RUN_FILES = (CONFIG_FILE, PROGRESS_FILE, SUMMARY_FILE, CHECKPOINT_FILE, CURVE_FILE, VIDEO_FILE)


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
    programs: Programs
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


def _prepare(
    resolved: ResolvedConfig, out: Path, devices: int | None, say: Callable[[str], None]
) -> _Run:
    # config.yaml records the batch that trains: a weak config's, multiplied out
    resolved = resolve_scaling(engine_resolved(resolved), devices)
    programs = build_programs(resolved, devices)
    say(machine.describe(programs.env))
    per_chunk, chunks = programs.trainer.steps_per_chunk, programs.trainer.num_chunks
    asked = getattr(resolved.agent, "total_steps", None)
    if asked is not None and asked != per_chunk * chunks:
        say(
            f"total_steps {asked} rounds up to whole chunks: {per_chunk * chunks} env steps "
            f"per seed ({chunks} chunks of {per_chunk})"
        )
    keys = seed_keys(resolved.train.seed, resolved.train.num_seeds)
    params_fn = jax.vmap(programs.trainer.policy_params)
    # the programs' own eval_shape: XLA options (jaxenvs.core.xla) refuse a nested trace
    template = programs.init_fn.eval_shape(keys)
    metric_shapes = programs.chunk_fn.eval_shape(template)[1]
    if LEVEL in programs.env.metric_keys:  # a curriculum: its mean level per chunk
        level = jax.ShapeDtypeStruct((resolved.train.num_seeds,), np.float32)
        metric_shapes = {**metric_shapes, LEVEL: level}
    columns = metric_columns(metric_shapes)
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
    run.programs.start_chunk(run.template)  # a chunk in stages compiles while init runs
    state = run.programs.init_fn(run.keys)
    rs = RunState(state, [], np.full((run.num_seeds, 0), -1.0, np.float32), False, 0)
    _save_checkpoint(run, clock, rs)
    return rs


def _resume(run: _Run, clock: _Clock) -> tuple[RunState, _Clock]:
    """The committed state of the checkpoint, progress.csv's rows up to it, and the clock
    counting the seconds already spent."""
    path, expected = run.out / CHECKPOINT_FILE, _identity(run)
    try:
        state, meta = checkpoint.load(path, run.template)
    except checkpoint.CheckpointError:
        # a state of another shape: say which setting differs (the engine, say) if the
        # record tells, else why the file does not fit
        meta = checkpoint.read(path)[1]["metadata"]
        checkpoint.check_matches(path, {k: meta.get(k) for k in expected}, expected)
        raise
    checkpoint.check_matches(path, {k: meta.get(k) for k in expected}, expected)
    start = int(meta["chunk"])
    clock = dataclasses.replace(
        clock,
        wall_before=float(meta["wall_seconds"]),
        cpu_before=float(meta.get("cpu_seconds", 0.0)),
    )
    top = np.asarray(meta["top_lengths"], np.float32).reshape(run.num_seeds, -1)
    rows = [r for r in read_progress(run.out / PROGRESS_FILE) if int(r["chunk"]) < start]
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
        row: dict[str, Any] = {c: format_value(metrics[c][k]) for c in run.columns if c in metrics}
        row.update(chunk=chunk, seed=k, wall_seconds=f"{wall:.3f}")
        row["cpu_seconds"] = f"{cpu:.3f}"
        row["eval_return"] = format_value(eval_mean)
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
    run.programs.start_evaluator()  # the chunk has compiled (jaxenvs.run.programs)
    metrics = jax.device_get(metrics)
    seconds = time.perf_counter() - last
    level = task_level(state) if LEVEL in run.columns else None
    if level is not None:
        metrics = {**metrics, LEVEL: level}
    eval_mean = math.nan
    if train_cfg.eval_every and (rs.chunk + 1) % train_cfg.eval_every == 0:
        returns, _, _ = run.programs.evaluate(run.params_fn(state), eval_key(train_cfg.seed))
        eval_mean = float(np.mean(returns))
    rows = rs.rows + _chunk_rows(run, clock, rs.chunk, metrics, eval_mean)
    finished = rs.chunk + 1 >= num_chunks
    if "active_envs" in metrics and not np.any(np.asarray(metrics["active_envs"]) > 0):
        finished = True
    nxt = RunState(state, rows, _top_lengths(rs.top, metrics), finished, rs.chunk + 1)
    write_progress(run.out / PROGRESS_FILE, run.columns, nxt.rows)
    _save_checkpoint(run, clock, nxt)
    return nxt, metrics, seconds


def _finish(
    run: _Run, clock: _Clock, rs: RunState, interrupted: bool, video: PolicyVideo | None
) -> dict[str, Any]:
    """The final evaluation, summary.json, the learning curve and (when ``video`` is
    given) the video of the best seed, drawn on its worker while the summary and the
    curve are written; returns the summary."""
    train_cfg, out = run.resolved.train, run.out
    wall = clock.wall()
    result = run.programs.evaluate(run.params_fn(rs.state), eval_key(train_cfg.seed))
    returns, trajectory, lengths = jax.device_get(result)
    returns = np.asarray(returns)
    if video is not None:
        best = int(np.argmax(returns.mean(axis=1)))
        video.draw(jax.tree.map(lambda x: x[best], trajectory), int(lengths[best]))
    summary = summarize(
        rs.rows, returns, rs.top, wall, rs.chunk, run.trainer.num_chunks, rs.finished
    )
    summary.update(env_id=run.resolved.env_id, algo=run.resolved.algo, interrupted=interrupted)
    summary["physics"] = run.programs.env.physics
    # process CPU time (all threads): on a shared, loaded machine a steadier figure than wall
    summary["cpu_seconds"] = round(clock.cpu(), 3)
    write_json(out / SUMMARY_FILE, summary)
    try:
        plot_curves([out], out / CURVE_FILE)
    except Exception as err:  # noqa: BLE001 - a plot must never lose the results
        run.say(f"no learning curve: {err}")
    if video is not None:
        video.wait()
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

    The run claims ``out_dir`` for its whole life (:func:`jaxenvs.files.claim_directory`):
    while another process holds it, :class:`jaxenvs.files.DirectoryBusy` is raised at
    once; a fresh run (not ``resume``) into a directory that holds a checkpoint raises
    ``FileExistsError``. Under the claim, temporary files an earlier, killed run left
    are removed.

    Ctrl-C waits for the chunk in flight (a compiled program cannot be stopped part
    way), commits it (progress.csv, checkpoint), writes the results so far, says how to
    resume and raises ``KeyboardInterrupt``. A second Ctrl-C stops at once, discarding
    the chunk in flight: the checkpoint on disk stays the last committed chunk's. A
    Ctrl-C before the first checkpoint (while compiling) saves nothing; the notice says
    there is nothing to resume, and the process ends once the chunk's compile, started on
    a background thread beside init's, has ended.
    """
    clock = _Clock(time.perf_counter(), time.process_time())
    say = log or ((lambda m: None) if quiet else (lambda m: print(m, file=sys.stderr)))
    out = Path(out_dir)
    with files.claim_directory(out, _owner(resolved, resume)):
        if not resume and (out / CHECKPOINT_FILE).exists():
            raise FileExistsError(f"{out} already holds a run; use --resume {out} or another --out")
        files.remove_temporaries(out, RUN_FILES)
        try:
            run = _prepare(resolved, out, devices, say)
            if resume:
                rs, clock = _resume(run, clock)
                if not rs.finished:
                    run.programs.start_chunk(run.template)
            else:
                rs = _start(run, clock)
        except KeyboardInterrupt:
            if not resume:
                say(f"interrupted before the first checkpoint: nothing to resume in {out}")
            raise
        return _loop(run, clock, rs, quiet, max_chunks)


def _owner(resolved: ResolvedConfig, resume: bool) -> str:
    """Who holds a run directory's claim, as the message of a refused second run says."""
    what = "resuming" if resume else "training"
    return (
        f"another run (pid {os.getpid()}, {what} {resolved.algo} on {resolved.env_id} "
        f"since {time.strftime('%Y-%m-%d %H:%M:%S')})"
    )


def _loop(
    run: _Run, clock: _Clock, rs: RunState, quiet: bool, max_chunks: int | None
) -> dict[str, Any]:
    """The chunks from ``rs`` on, then the results (see :func:`train`)."""
    out, say, resolved = run.out, run.say, run.resolved
    num_chunks, steps = run.trainer.num_chunks, run.trainer.steps_per_chunk
    stop = num_chunks if max_chunks is None else min(num_chunks, rs.chunk + max_chunks)
    bar = ProgressBar(
        num_chunks * steps, rs.chunk * steps, quiet, f"{resolved.algo} {resolved.env_id}"
    )
    interrupted = False
    # the video's renderer and the plot's imports are made ready while the chunks run
    video = PolicyVideo(run.programs.env, out / VIDEO_FILE, say) if resolved.train.video else None
    preload_plotting()
    try:
        # A first Ctrl-C only asks to stop after the running chunk is committed. A second
        # one (KeyboardInterrupt inside _run_chunk) discards the chunk in flight: ``rs``
        # stays the previous chunk's, which is exactly what the checkpoint on disk holds.
        try:
            with _StopRequest(say) as stop_request:
                while rs.chunk < stop and not rs.finished and not stop_request.asked:
                    rs, metrics, seconds = _run_chunk(run, clock, rs)
                    bar.update(steps, progress_postfix(metrics, seconds, steps * run.num_seeds))
                interrupted = stop_request.asked
        except KeyboardInterrupt:
            interrupted = True
            write_progress(out / PROGRESS_FILE, run.columns, rs.rows)
        finally:
            bar.close()
        if interrupted:
            say(
                f"interrupted: results and checkpoint are of chunk {rs.chunk}/{num_chunks}; "
                f"continue with: jaxenvs train --resume {out}"
            )
        summary = _finish(run, clock, rs, interrupted, None if interrupted else video)
    finally:
        if video is not None:  # frees the worker (a no-op once the video is written)
            video.cancel()
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
