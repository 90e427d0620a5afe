"""The real-time deploy loop: an exported policy driving a robot at the task's control rate.

Every control period ``dt`` (``env.control_dt``), at tick ``t0 + k dt``, the loop takes
the newest sensor frame, computes the observation with the task's own function
(:class:`~jaxenvs.robots.interface.HostTask`), runs the policy, and sends the command.

* **Deadline miss**: the command of a tick went out more than half a period after the
  tick. Ticks the loop slept through entirely are skipped and counted as misses too.
* **Safety**: the loop stops, commands a hold and raises :class:`DeployError` (one line
  naming the cause) when the link fails or the robot sends something malformed
  (:class:`~jaxenvs.robots.interface.LinkError`), no sensor frame arrives for
  ``sensor_timeout_ms``, the policy's output or the observation is not finite, a
  command goes out more than ``max_late_ms`` after its tick (an overrun), the log cannot
  be written (:class:`~jaxenvs.deploy.log.LogError`: a full disk), or anything else fails
  (named with its exception's type). The log is finished on every exit it can be.
* **Ground truth**: a simulated robot's privileged state gives the task's state (e.g.
  Reacher's target), reward and termination through the task's own functions: the summary's
  ``return`` and ``terminated``. A robot without it reports ``return: null``; a task
  input (the target, a joystick command) then comes from
  :class:`~jaxenvs.deploy.commands.CommandInput`. The loop ends at termination (the
  episode is over), holding.
"""

from __future__ import annotations

import dataclasses
import math
import os
import sys
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from jaxenvs.deploy.commands import CommandInput
from jaxenvs.deploy.log import LogError
from jaxenvs.robots.interface import LinkError


class DeployError(RuntimeError):
    """The run stopped on a failure; the message is one line naming the cause."""


# ---------------------------------------------------------------------------- the policy
#: the first bytes of a zip archive (an ``.npz``); an ONNX model is a protobuf, with none
ZIP_MAGIC = (b"PK\x03\x04", b"PK\x05\x06")


def policy_format(path: Path) -> str:
    """``npz`` or ``onnx``: what the file at ``path`` holds, by its first bytes (a zip
    archive is an ``.npz``; anything else is read as ONNX), whatever its suffix;
    ``ValueError`` when there is no file."""
    try:
        with open(path, "rb") as f:
            head = f.read(4)
    except OSError as err:
        raise ValueError(f"no policy file at {path} ({err.strerror or err})") from None
    if not head:
        raise ValueError(f"{path}: an empty file, not an exported policy")
    return "npz" if head in ZIP_MAGIC else "onnx"


def _onnx_session(path: Path) -> Any:
    """An onnxruntime session of ``path`` (one thread); ``ValueError`` in one line when
    onnxruntime is missing or cannot read the file as a model taking ``obs`` and giving
    ``action``."""
    try:
        import onnxruntime
    except ImportError:
        raise ValueError(
            "an .onnx policy needs onnxruntime: pip install 'jaxenvs[export]'"
        ) from None
    options = onnxruntime.SessionOptions()
    options.intra_op_num_threads = options.inter_op_num_threads = 1
    try:
        session = onnxruntime.InferenceSession(
            str(path), options, providers=["CPUExecutionProvider"]
        )
    except Exception as err:  # noqa: BLE001 (onnxruntime's errors share no base class)
        first = (str(err).strip().splitlines() or [""])[0][:160]
        raise ValueError(
            f"{path}: not a readable ONNX model or .npz ({type(err).__name__}: {first})"
        ) from None
    if [i.name for i in session.get_inputs()] != ["obs"] or "action" not in [
        o.name for o in session.get_outputs()
    ]:
        raise ValueError(f"{path}: not an exported jaxenvs policy (no obs -> action graph)")
    return session


class HostPolicy:
    """An exported policy, read by its content (:func:`policy_format`): ONNX through
    onnxruntime, or an ``.npz`` through the numpy runtime. ``act(obs) -> (action,
    finite)`` where ``finite`` says the network's output (the logits of a discrete policy
    from an ``.npz``) was finite. A file that is neither, or lacks the metadata the loop
    needs (``env_id``, a finite positive ``control_dt``), is a one-line ``ValueError``."""

    def __init__(self, path: str | Path) -> None:
        path = Path(path)
        self.path = path
        self.format = policy_format(path)
        self._npz: Any = None
        if self.format == "onnx":
            self._session = _onnx_session(path)
            self.metadata = dict(self._session.get_modelmeta().custom_metadata_map)
        else:
            from jaxenvs.deploy.runtime import NumpyPolicy

            self._npz = NumpyPolicy.load(path)
            self.metadata = dict(self._npz.metadata)
        if "env_id" not in self.metadata or "control_dt" not in self.metadata:
            raise ValueError(f"{path}: not an exported jaxenvs policy (no env_id/control_dt)")
        try:
            dt = float(self.metadata["control_dt"])
        except ValueError:
            dt = math.nan
        if not (math.isfinite(dt) and dt > 0):
            raise ValueError(f"{path}: corrupt policy metadata (control_dt)")
        self.discrete = self.metadata.get("discrete") == "1"

    def act(self, obs: np.ndarray) -> tuple[np.ndarray, bool]:
        """The greedy action of one observation, and whether the output was finite."""
        x = np.asarray(obs, np.float32)[None]
        if self._npz is not None:
            out = self._npz.logits(x)[0]
            finite = bool(np.all(np.isfinite(out)))
            if self.discrete:
                return np.asarray(np.argmax(out), np.int64), finite
            return np.clip(out, -1.0, 1.0).astype(np.float32), finite
        action = self._session.run(["action"], {"obs": x})[0][0]
        return action, bool(np.all(np.isfinite(action)))


# ----------------------------------------------------------------------------- the loop
@dataclasses.dataclass(frozen=True)
class LoopOptions:
    """How long the loop runs, and when it stops on its own.

    Attributes:
      seconds: how long to run.
      sensor_timeout_ms: the longest wait for a fresh sensor frame before stopping.
      max_late_ms: a command later than this after its tick stops the run (overrun).
      first_frame_s: how long to wait for the robot's first sensor frame.
    """

    seconds: float
    sensor_timeout_ms: float = 250.0
    max_late_ms: float = 100.0
    first_frame_s: float = 5.0


@dataclasses.dataclass
class Record:
    """What the loop measured (the summary's numbers)."""

    dt: float
    steps: int = 0
    misses: int = 0
    terminated: bool = False
    ret: float | None = None
    sends: list[float] = dataclasses.field(default_factory=list)
    lateness: list[float] = dataclasses.field(default_factory=list)
    ages: list[float] = dataclasses.field(default_factory=list)
    rtts: list[float] = dataclasses.field(default_factory=list)
    tracking: dict[str, list[float]] = dataclasses.field(default_factory=dict)
    error: str | None = None


#: the SCHED_FIFO priority of ``--realtime`` (the middle of Linux's 1..99)
RT_PRIORITY = 50


def raise_priority() -> str:
    """Run this thread (and the threads it starts) under Linux's real-time ``SCHED_FIFO``
    scheduler at :data:`RT_PRIORITY`, so that other processes on a busy computer do not
    delay the control loop; what was done, as a few words ("SCHED_FIFO 50", or why not).
    The loop sleeps most of each period, so it leaves the CPU to others."""
    try:
        os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(RT_PRIORITY))
    except (AttributeError, PermissionError, OSError) as err:
        return f"normal priority ({type(err).__name__}: needs Linux and CAP_SYS_NICE)"
    return f"SCHED_FIFO {RT_PRIORITY}"


def _sleep_until(t: float) -> None:
    """Sleep to within 0.3 ms of ``t``, then spin (time.sleep alone wakes ~0.1-1 ms late)."""
    while True:
        left = t - time.monotonic()
        if left <= 0:
            return
        if left > 3e-4:
            time.sleep(left - 3e-4)


class _Step:
    """The loop's state between ticks: last frame, truth, action, sends pending an ack."""

    def __init__(self, host: Any, commands: CommandInput | None) -> None:
        self.host, self.commands = host, commands
        self.frame_seq = -1
        self.truth: tuple[int, dict[str, np.ndarray]] | None = None
        self.action: np.ndarray | None = None
        #: the last actions applied (the policy's, with a task's prior where it has one;
        #: unfiltered: what the observation holds), the most recent first (zeros before the
        #: first)
        self.sent: np.ndarray = host.zero_history
        #: the last command sent (per actuator; zeros before the first)
        self.command: np.ndarray = host.zero_command
        self.task: Any = host.default_task_state
        self.pending: dict[int, float] = {}


def _check_frame(link: Any, opts: LoopOptions, now: float) -> Any:
    frame = link.latest()
    if frame is None or now - frame.received > opts.sensor_timeout_ms / 1e3:
        raise DeployError(f"no sensor message for {opts.sensor_timeout_ms:g} ms")
    return frame


def _account_truth(link: Any, st: _Step, rec: Record, log: Any, in_force: Any) -> None:
    """Reward and termination of every ground-truth state received since the last step
    (with the action then in force), and the task's state of the newest."""
    for truth in link.truths() if hasattr(link, "truths") else []:
        if log is not None:
            log.write("/robot/state", {"seq": truth[0], **truth[1]})
        prev = truth if st.truth is None else st.truth
        action = st.host.zero_action if in_force is None else in_force
        task, reward, term = st.host.of_truth(prev[1], truth[1], action)
        if st.commands is None:
            st.task = task
        if st.truth is not None and in_force is not None and not rec.terminated:
            if not math.isnan(reward):
                rec.ret = (rec.ret or 0.0) + reward
            rec.terminated = term
            if truth[0] == prev[0] + 1:  # one control period apart
                for name, err in st.host.tracking(prev[1], truth[1], st.task).items():
                    rec.tracking.setdefault(name, []).append(err)
        st.truth = truth


def _one_step(
    link: Any,
    policy: HostPolicy,
    st: _Step,
    rec: Record,
    k: int,
    t0: float,
    tick: float,
    opts: LoopOptions,
    log: Any,
) -> None:
    frame = _check_frame(link, opts, time.monotonic())
    if st.commands is not None:
        value = st.commands.at(tick - t0)
        if value is not None:
            st.task = st.host.with_input(st.task, value)
    # a task with a clock: control periods since the start, missed ones included
    task = st.host.with_clock(st.task, k)
    obs = st.host.observe(frame.readings, st.host.with_action_history(task, st.sent))
    if not np.all(np.isfinite(obs)):
        raise DeployError("the observation is not finite")
    action, finite = policy.act(obs)
    if not finite:
        raise DeployError("the policy's output is not finite")
    action = st.host.prior_action(task, action)  # a task's prior (its env applies it too)
    command = st.host.actuator_command(action, st.command)
    link.send(k, command)
    st.command = command
    sent = time.monotonic()
    in_force, st.action, st.pending[k] = st.action, action, sent
    st.sent = st.host.pushed(st.sent, action)
    late = sent - tick
    if late > opts.max_late_ms / 1e3:
        raise DeployError(f"overrun: step {k}'s command went out {late * 1e3:.1f} ms late")
    rec.steps += 1
    rec.misses += late > rec.dt / 2
    rec.sends.append(sent)
    rec.lateness.append(late)
    rec.ages.append(sent - frame.received)
    # after the command is out: round trips, and the ground truth's reward and task state
    # (a frame acknowledging a command sent after it arrived is no round trip)
    for seq in [s for s in st.pending if s <= frame.acked]:
        if st.pending[seq] <= frame.received:
            rec.rtts.append(frame.received - st.pending[seq])
        del st.pending[seq]
    _account_truth(link, st, rec, log, in_force)
    if log is not None:
        if frame.seq != st.frame_seq:
            log.write(
                "/robot/sensors",
                {
                    "seq": frame.seq,
                    "stamp": frame.stamp,
                    "acked": frame.acked,
                    "readings": frame.readings,
                },
            )
        log.write(
            "/deploy/command",
            {
                "step": k,
                "seq": k,
                "tick": tick - t0,
                "sent": sent - t0,
                "obs": obs,
                "action": action,
                "command": command,
                "task": _task_json(task),
            },
        )
    st.frame_seq = frame.seq


def _task_json(task: Any) -> Any:
    leaves = [np.asarray(x).tolist() for x in _leaves(task)]
    return leaves[0] if len(leaves) == 1 else leaves


def _leaves(tree: Any) -> list[Any]:
    import jax

    return list(jax.tree.leaves(tree))


def _first_frame(link: Any, st: _Step, rec: Record, opts: LoopOptions, log: Any) -> None:
    """Wait for the first typed task input when the observation needs one, then for the
    robot's first sensor frame (and its first ground truth, when it sends one: the task's
    own state may come from it)."""
    if st.commands is not None and st.host.needs_input and st.commands.at(0.0) is None:
        print("type the task input (v1 v2 ...) to start", file=sys.stderr, flush=True)
        while st.commands.at(0.0) is None:
            if st.commands.exhausted and st.commands.at(0.0) is None:  # set before ended
                raise DeployError("standard input ended before the first task input")
            time.sleep(0.01)
    end = time.monotonic() + opts.first_frame_s
    truth = getattr(link, "privileged", False)
    while link.latest() is None or (truth and st.truth is None):
        if time.monotonic() > end:
            raise DeployError(f"no sensor message within {opts.first_frame_s:g} s")
        if truth:
            _account_truth(link, st, rec, log, None)
        time.sleep(1e-3)


def check_deploy_fields(env: Any, metadata: dict[str, str]) -> None:
    """Raise ``ValueError`` naming the first of the task's ``deploy_fields`` (the config
    fields the loop depends on: an observation's layout, a command filter) whose value in
    the policy's metadata (``env_config``; a field it does not hold has the config class's
    default) differs from ``env``'s."""
    import json

    trained = json.loads(metadata.get("env_config", "{}"))
    default = type(env.config)()
    for name in getattr(env, "deploy_fields", ()):
        want, have = trained.get(name, getattr(default, name)), getattr(env.config, name)
        if want != have:
            raise ValueError(
                f"the policy was trained with {name}={want!r}, the deploy task has "
                f"{name}={have!r}: build it with jaxenvs.make(..., {name}={want!r})"
            )


def run(
    link: Any,
    host: Any,
    policy: HostPolicy,
    opts: LoopOptions,
    log: Any = None,
    commands: CommandInput | None = None,
) -> Record:
    """Drive ``link`` (connected) for ``opts.seconds``; a :class:`Record` of the run.
    Always holds the robot at the end; on any failure (an interrupt included)
    ``record.error`` names it, and the robot was told to hold. The one exception raised is
    the ``ValueError`` of a policy whose metadata disagrees with the host's task on a
    deploy field, before the robot is driven (:func:`check_deploy_fields`)."""
    metadata = getattr(policy, "metadata", None)
    if metadata is not None:
        check_deploy_fields(host.env, metadata)
    dt = float(host.env.control_dt)
    rec = Record(dt=dt)
    st = _Step(host, commands)
    try:
        _first_frame(link, st, rec, opts, log)
        t0 = time.monotonic()
        total = max(1, round(opts.seconds / dt))
        k = 0
        while k < total and not rec.terminated:
            tick = t0 + k * dt
            _sleep_until(tick)
            _one_step(link, policy, st, rec, k, t0, tick, opts, log)
            behind = int((time.monotonic() - t0) / dt) - k  # ticks slept through
            k += max(1, behind)
            rec.misses += max(0, behind - 1)
    except (DeployError, LinkError, LogError) as err:
        rec.error = str(err)
    except KeyboardInterrupt:
        rec.error = "interrupted"
    except Exception as err:  # noqa: BLE001 (whatever fails, the robot is held and told why)
        rec.error = f"unexpected {type(err).__name__}: {str(err)[:160]}".replace("\n", " ")
    finally:
        reason = rec.error or ("terminated" if rec.terminated else "done")
        link.hold(reason)
        if log is not None:
            try:
                log.write("/deploy/event", {"event": "hold", "reason": reason})
            except LogError as err:
                rec.error = rec.error or str(err)
    return rec


def _pct(values: Sequence[float], q: float) -> float | None:
    return float(np.percentile(values, q)) * 1e3 if values else None


def summary(rec: Record, link: Any, policy: HostPolicy, env_id: str, seconds: float) -> dict:
    """The run's JSON summary (``docs/deploy.md`` lists the fields)."""
    periods = list(np.diff(rec.sends)) if len(rec.sends) > 1 else []
    return {
        "env_id": env_id,
        "policy": str(policy.path),
        "policy_format": policy.format,
        "seconds": seconds,
        "steps": rec.steps,
        "terminated": rec.terminated,
        "return": rec.ret,
        "target_period_ms": rec.dt * 1e3,
        "period_ms_mean": float(np.mean(periods)) * 1e3 if periods else None,
        "period_ms_p99": _pct(periods, 99),
        "period_ms_max": _pct(periods, 100),
        "deadline_misses": rec.misses,
        "late_ms_p50": _pct(rec.lateness, 50),
        "late_ms_p99": _pct(rec.lateness, 99),
        "sensor_age_ms_mean": float(np.mean(rec.ages)) * 1e3 if rec.ages else None,
        "round_trip_ms_p50": _pct(rec.rtts, 50),
        "round_trip_ms_p99": _pct(rec.rtts, 99),
        "tracking_error_rms": (
            {k: float(np.sqrt(np.mean(np.square(v)))) for k, v in rec.tracking.items()}
            if rec.tracking
            else None
        ),
        "tracking_steps": max((len(v) for v in rec.tracking.values()), default=0),
        "bad_messages": dict(getattr(link, "counts", {})),
        "robot_bad_messages": dict(getattr(link, "robot_counts", {})),
        "error": rec.error,
    }


def one_line(s: dict) -> str:
    """The summary as one line."""

    def f(x: Any, fmt: str = ".2f") -> str:
        return "n/a" if x is None or (isinstance(x, float) and math.isnan(x)) else format(x, fmt)

    ret = f(s["return"], ".1f")
    return (
        f"{s['env_id']}: {s['steps']} steps, return {ret}, "
        f"{'terminated' if s['terminated'] else 'not terminated'}, period "
        f"{f(s['period_ms_mean'])} ms mean / {f(s['period_ms_p99'])} ms p99 "
        f"(target {s['target_period_ms']:.2f}), {s['deadline_misses']} deadline misses, "
        f"round trip {f(s['round_trip_ms_p50'])} ms p50"
        + "".join(
            f", {k} tracking error {v:.3f} RMS"
            for k, v in (s.get("tracking_error_rms") or {}).items()
        )
    )


__all__ = [
    "DeployError",
    "HostPolicy",
    "LoopOptions",
    "Record",
    "one_line",
    "run",
    "summary",
]
