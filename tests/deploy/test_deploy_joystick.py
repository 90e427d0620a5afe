"""``jaxenvs deploy`` on ``HexapodJoystick-v0`` through the simulated robot: the command
from a script, the last actions in the observation (of the trained env's
``action_delay_max``), and the tracking errors of the summary measured on the simulated
robot's ground truth.

The policy is exported as a one-layer ``.npz`` whose action is a constant (its bias): the
hexapod stands still, so the errors are the commanded speeds themselves. No training.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import jax
import numpy as np
import pytest

import jaxenvs
from jaxenvs.deploy import loop
from jaxenvs.deploy.export import deploy_config, env_config_changes, npz_bytes
from jaxenvs.deploy.log import read_log
from jaxenvs.deploy.runtime import FORMAT, FORMAT_VERSION, NumpyPolicy
from jaxenvs.robots.interface import HostTask, SensorFrame, spec_of
from jaxenvs.tasks.hexapod.joystick import JoystickConfig

ROOT = Path(__file__).resolve().parents[2]
ACTION = 0.05  # every joint slightly off the neutral stance: the robot stands


def _constant_policy(path: Path, **env_config: object) -> Path:
    """A HexapodJoystick-v0 policy (of the env with ``env_config``) that always acts
    :data:`ACTION` on every joint."""
    size = jaxenvs.make("HexapodJoystick-v0", physics="c", **env_config).observation_size
    meta = {
        "format": FORMAT,
        "format_version": FORMAT_VERSION,
        "env_id": "HexapodJoystick-v0",
        "observation_size": str(size),
        "action_size": "18",
        "discrete": "0",
        "control_dt": "0.05",
        "activation": "tanh",
        "env_config": json.dumps(env_config),
    }
    kernel, bias = np.zeros((size, 18), np.float32), np.full(18, ACTION, np.float32)
    path.write_bytes(npz_bytes(NumpyPolicy((kernel,), (bias,), None, False, meta)))
    return path


def _deploy(tmp_path: Path, script: str, seconds: float, **env_config: object) -> tuple[dict, dict]:
    policy = _constant_policy(tmp_path / "p.npz", **env_config)
    commands = tmp_path / "script.txt"
    commands.write_text(script)
    summary, log = tmp_path / "s.json", tmp_path / "l.mcap"
    argv = [sys.executable, "-m", "jaxenvs", "deploy", str(policy), "--env"]
    argv += ["HexapodJoystick-v0", "--robot", "sim", "--seconds", f"{seconds:g}"]
    argv += ["--command", str(commands), "--summary", str(summary), "--log", str(log)]
    env = {**os.environ, "PYTHONPATH": str(ROOT), "MUJOCO_GL": "egl"}
    done = subprocess.run(argv, capture_output=True, text=True, env=env, timeout=120)
    assert done.returncode == 0, done.stderr
    assert "lin tracking error" in done.stdout.strip().splitlines()[-1]
    return json.loads(summary.read_text()), read_log(log)


@pytest.mark.full  # a real-time subprocess run; the default tier deploys CartPole so
def test_joystick_deploys_with_its_command_and_reports_tracking_errors(tmp_path):
    """2 s standing still: 1 s under a forward command (0.3 m/s), 1 s under a yaw rate
    (0.5 rad/s). The errors are those speeds (RMS over the halves), the robot never
    moved or fell, and each observation holds the command in force and the last actions.
    The policy was trained with ``action_delay_max=2`` (its metadata's env config): the
    loop builds the task with it, so the observation holds the last three actions sent."""
    s, log = _deploy(tmp_path, "0 0.3 0 0\n1 0 0 0.5\n", 2.0, action_delay_max=2)
    assert s["steps"] == 40 and s["error"] is None and s["terminated"] is False
    assert s["return"] is None  # the task's reward needs the servo forces: not in the truth
    assert s["tracking_steps"] >= 35
    rms = s["tracking_error_rms"]
    assert rms["lin"] == pytest.approx(0.3 / np.sqrt(2), abs=0.03)
    assert rms["yaw"] == pytest.approx(0.5 / np.sqrt(2), abs=0.05)
    obs = np.asarray([c["obs"] for c in log["/deploy/command"]])
    assert np.allclose(obs[:20, -3:], [0.3, 0.0, 0.0]) and np.allclose(obs[20:, -3:], [0, 0, 0.5])
    assert obs.shape == (40, 99)
    history = obs[:, 42:96].reshape(40, 3, 18)  # the newest first
    for i in range(3):
        assert np.all(history[: i + 1, i] == 0.0) and np.allclose(history[i + 1 :, i], ACTION)
    assert [c["task"][0] for c in log["/deploy/command"]][-1] == pytest.approx([0, 0, 0.5])


def test_exported_env_config_is_what_differs_from_the_defaults():
    config = JoystickConfig(action_delay_max=2, vx_range=(-1.0, 1.0), obs_noise=0.0)
    assert env_config_changes(config) == {"action_delay_max": 2, "vx_range": [-1.0, 1.0]}
    assert json.loads(json.dumps(env_config_changes(config))) == env_config_changes(config)


class _Link:
    """A robot whose sensor frame the test sets; it keeps what the loop sends."""

    def __init__(self) -> None:
        self.frame: SensorFrame | None = None
        self.sent: list[np.ndarray] = []

    def latest(self) -> SensorFrame | None:
        return self.frame

    def send(self, seq: int, command: np.ndarray) -> None:
        self.sent.append(command)


class _Policy:
    """Acts the given actions in turn; keeps the observations it was given."""

    def __init__(self, actions: np.ndarray) -> None:
        self.actions, self.seen = actions, []

    def act(self, obs: np.ndarray) -> tuple[np.ndarray, bool]:
        self.seen.append(obs)
        return self.actions[len(self.seen) - 1], True


class _Commands:
    value: np.ndarray

    def at(self, t: float) -> np.ndarray:
        return self.value


def _warmed_host(env: Any, env_id: str) -> HostTask:
    """``env``'s host task, warmed on the readings of ``env_id``'s robot at ``qpos0``."""
    host = HostTask(env)
    model = env.sim.physics_mj_model
    truth = {"qpos": model.qpos0.copy(), "qvel": np.zeros(model.nv), "mocap_pos": np.zeros((0, 3))}
    host.warm(spec_of(env, env_id).sizes(), truth)
    return host


def _gait_env(**extra: object) -> Any:
    """A small ``HexapodJoystickRough-v0`` (flat tiles) with its gait prior at 2.5 Hz and
    every command non-zero, under MuJoCo C."""
    return jaxenvs.make(
        "HexapodJoystickRough-v0",
        physics="c",
        levels=3,
        terrain_types=("flat",),
        gait_frequency=2.5,
        zero_probability=0.0,
        **extra,
    )


def _loop_beside_env(
    env: Any, actions: np.ndarray, delay: int, env_id: str = "HexapodJoystick-v0"
) -> tuple[_Link, list]:
    """The deploy loop's steps on the readings of ``env`` (a ``HexapodJoystick-v0``, or
    the ``env_id`` of a task of its family), from a reset whose drawn action delay is
    ``delay``, the env stepped with the same ``actions``: asserts each step's loop
    observation is the env's; returns the link (what the loop sent) and the env's
    ``data.ctrl`` after each step."""
    host = _warmed_host(env, env_id)
    link, policy, commands = _Link(), _Policy(actions.astype(np.float32)), _Commands()
    st, rec = loop._Step(host, commands), loop.Record(dt=env.control_dt)  # type: ignore[arg-type]
    opts = loop.LoopOptions(seconds=1.0, sensor_timeout_ms=1e6, max_late_ms=1e6)
    keys = jax.random.split(jax.random.key(0), 32)
    # jitted: an eager call compiles each of its operations on its own (seconds here)
    delays = np.asarray(jax.jit(jax.vmap(env.reset))(keys).extras.delay)
    state = jax.jit(env.reset)(keys[int(np.argmax(delays == delay))])
    assert int(state.extras.delay) == delay
    step, sense = jax.jit(env.step), jax.jit(env.robot.sense)
    observable = env.robot.observable()
    t0, ctrls = time.monotonic(), []
    for k in range(len(actions)):
        readings = {n: np.asarray(v) for n, v in sense(state.data).items()}
        readings = {n: v for n, v in readings.items() if n in observable}
        link.frame = SensorFrame(k, 0.0, readings, time.monotonic())
        commands.value = np.asarray(state.extras.command)
        loop._one_step(link, policy, st, rec, k, t0, time.monotonic(), opts, None)
        np.testing.assert_allclose(policy.seen[k], state.obs, atol=1e-6)
        state = step(state, actions[k])
        ctrls.append(np.asarray(state.data.ctrl))
    return link, ctrls


def test_loop_observation_is_the_envs_with_delayed_actions():
    """Step by step, the deploy loop's observation of the env's readings (its own task
    state: the command in force and the actions it sent) is the env's observation, for a
    task with ``action_delay_max=2`` whose env draws a delay of 2."""
    env = jaxenvs.make("HexapodJoystick-v0", physics="c", action_delay_max=2, command_interval=4)
    actions = np.asarray(jax.random.uniform(jax.random.key(1), (8, 18), minval=-0.4, maxval=0.4))
    link, _ = _loop_beside_env(env, actions, delay=2)
    assert len(link.sent) == 8


def test_joystick_command_script_of_another_size_is_refused(tmp_path):
    """A script line of two values for a three-value command: one line, status 2."""
    policy, commands = _constant_policy(tmp_path / "p.npz"), tmp_path / "script.txt"
    commands.write_text("0 0.3 0\n")
    argv = [sys.executable, "-m", "jaxenvs", "deploy", str(policy), "--env"]
    argv += ["HexapodJoystick-v0", "--robot", "sim", "--seconds", "1", "--command", str(commands)]
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    done = subprocess.run(argv, capture_output=True, text=True, env=env, timeout=120)
    assert done.returncode == 2
    assert "the command at 0 s has 2 values, HexapodJoystick-v0 takes 3" in done.stderr


@pytest.mark.parametrize("delay", [0, 2])
def test_loop_sends_the_envs_filtered_servo_targets(delay):
    """With ``action_filter``, the loop sends the low-passed command (the policy's actions
    filtered with the command sent before) whose servo targets are the env's for the same
    actions, step by step (with an env action delay of ``delay`` steps: the command sent
    ``delay`` steps before, zero targets before the first); the observation still holds
    the policy's own actions."""
    env = jaxenvs.make(
        "HexapodJoystick-v0",
        physics="c",
        action_filter=0.5,
        command_interval=50,
        action_delay_max=delay,
    )
    actions = np.asarray(jax.random.uniform(jax.random.key(2), (6, 18), minval=-0.4, maxval=0.4))
    link, ctrls = _loop_beside_env(env, actions, delay)
    for k, ctrl in enumerate(ctrls):
        sent = link.sent[k - delay] if k >= delay else np.zeros(18)
        targets = np.asarray(env.robot.command(np.asarray(sent, np.float32)))
        np.testing.assert_allclose(targets, ctrl, atol=1e-5)
    # filtered: the second command is neither the second action nor the first command
    assert not np.allclose(link.sent[1], actions[1], atol=1e-3)
    np.testing.assert_allclose(link.sent[0], 0.5 * actions[0], atol=1e-6)


def test_loop_applies_the_rough_gait_prior_as_its_env_does():
    """``HexapodJoystickRough-v0`` with its gait prior and the command filter: step by
    step the loop's observation (its clock's phase among it) is the env's, and the
    commands it sends (the policy's actions plus the prior, filtered) drive the env's
    servo targets; the prior lifts the femurs the policy did not."""
    env = _gait_env(action_filter=0.5, command_interval=50)
    assert env.observation_size == 65
    actions = np.asarray(jax.random.uniform(jax.random.key(3), (8, 18), minval=-0.2, maxval=0.2))
    link, ctrls = _loop_beside_env(env, actions, 0, "HexapodJoystickRough-v0")
    for k, ctrl in enumerate(ctrls):
        targets = np.asarray(env.robot.command(np.asarray(link.sent[k], np.float32)))
        np.testing.assert_allclose(targets, ctrl, atol=1e-5)
    femurs = np.asarray(link.sent)[:, 1::3] - 0.5 * actions[:, 1::3]  # past the filter's share
    assert femurs.max() > 0.1  # lifted past anything the policy's +-0.2 gave


def test_the_loops_gait_clock_counts_missed_periods():
    """The loop's clock is its tick index: after ticks 0 and 3 (two missed), the second
    observation holds the phase of three control periods and the second action sent
    carries the prior's lift at that phase."""
    env = _gait_env()
    host = _warmed_host(env, "HexapodJoystickRough-v0")
    link, policy, commands = _Link(), _Policy(np.zeros((2, 18), np.float32)), _Commands()
    commands.value = np.asarray([0.2, 0.0, 0.0], np.float32)
    st, rec = loop._Step(host, commands), loop.Record(dt=env.control_dt)  # type: ignore[arg-type]
    opts = loop.LoopOptions(seconds=1.0, sensor_timeout_ms=1e6, max_late_ms=1e6)
    state = jax.jit(env.reset)(jax.random.key(0))
    readings = {n: np.asarray(v) for n, v in jax.jit(env.robot.sense)(state.data).items()}
    readings = {n: v for n, v in readings.items() if n in env.robot.observable()}
    t0 = time.monotonic()
    for k in (0, 3):
        link.frame = SensorFrame(k, 0.0, readings, time.monotonic())
        loop._one_step(link, policy, st, rec, k, t0, time.monotonic(), opts, None)
    angle = 2 * np.pi * 2.5 * env.control_dt * 3
    np.testing.assert_allclose(policy.seen[1][-5:-3], [np.sin(angle), np.cos(angle)], atol=1e-6)
    lift = np.asarray(env.gait_offset(jax.numpy.int32(3), commands.value))
    assert lift[1::3].max() > 0.1
    np.testing.assert_allclose(link.sent[1], lift, atol=1e-6)  # no filter: the lift itself


def test_loop_refuses_a_task_built_without_the_policys_filter():
    """A policy trained with ``action_filter=0.5`` (its metadata's env config) driven
    through a task built without it: ``loop.run`` raises naming the field, before the
    robot is driven; the exported metadata carries every deploy field."""
    env = jaxenvs.make("HexapodJoystick-v0", physics="c")
    meta = {"env_config": json.dumps({"action_filter": 0.5})}
    with pytest.raises(ValueError, match="action_filter=0.5"):
        loop.check_deploy_fields(env, meta)
    filtered = jaxenvs.make("HexapodJoystick-v0", physics="c", action_filter=0.5)
    loop.check_deploy_fields(filtered, meta)
    loop.check_deploy_fields(env, {"env_config": "{}"})  # the defaults: no filter, no delay
    assert deploy_config(JoystickConfig(), env) == {"action_delay_max": 0, "action_filter": 0.0}


def test_action_filter_outside_its_range_is_refused():
    with pytest.raises(ValueError, match="action_filter"):
        jaxenvs.make("HexapodJoystick-v0", physics="c", action_filter=1.0)
