"""``jaxenvs deploy`` on ``HexapodJoystick-v0`` through the simulated robot: the command
from a script, the last action in the observation, and the tracking errors of the summary
measured on the simulated robot's ground truth.

The policy is exported as a one-layer ``.npz`` whose action is a constant (its bias): the
hexapod stands still, so the errors are the commanded speeds themselves. No training.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from jaxenvs.deploy.export import npz_bytes
from jaxenvs.deploy.log import read_log
from jaxenvs.deploy.runtime import FORMAT, FORMAT_VERSION, NumpyPolicy

ROOT = Path(__file__).resolve().parents[1]
ACTION = 0.05  # every joint slightly off the neutral stance: the robot stands


def _constant_policy(path: Path) -> Path:
    """A HexapodJoystick-v0 policy that always acts :data:`ACTION` on every joint."""
    meta = {
        "format": FORMAT,
        "format_version": FORMAT_VERSION,
        "env_id": "HexapodJoystick-v0",
        "observation_size": "63",
        "action_size": "18",
        "discrete": "0",
        "control_dt": "0.05",
        "activation": "tanh",
    }
    kernel, bias = np.zeros((63, 18), np.float32), np.full(18, ACTION, np.float32)
    path.write_bytes(npz_bytes(NumpyPolicy((kernel,), (bias,), None, False, meta)))
    return path


def _deploy(tmp_path: Path, script: str, seconds: float) -> tuple[dict, dict]:
    policy, commands = _constant_policy(tmp_path / "p.npz"), tmp_path / "script.txt"
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


def test_joystick_deploys_with_its_command_and_reports_tracking_errors(tmp_path):
    """2 s standing still: 1 s under a forward command (0.3 m/s), 1 s under a yaw rate
    (0.5 rad/s). The errors are those speeds (RMS over the halves), the robot never
    moved or fell, and each observation holds the command in force and the last action."""
    s, log = _deploy(tmp_path, "0 0.3 0 0\n1 0 0 0.5\n", 2.0)
    assert s["steps"] == 40 and s["error"] is None and s["terminated"] is False
    assert s["return"] is None  # the task's reward needs the servo forces: not in the truth
    assert s["tracking_steps"] >= 35
    rms = s["tracking_error_rms"]
    assert rms["lin"] == pytest.approx(0.3 / np.sqrt(2), abs=0.03)
    assert rms["yaw"] == pytest.approx(0.5 / np.sqrt(2), abs=0.05)
    obs = np.asarray([c["obs"] for c in log["/deploy/command"]])
    assert np.allclose(obs[:20, -3:], [0.3, 0.0, 0.0]) and np.allclose(obs[20:, -3:], [0, 0, 0.5])
    assert np.all(obs[0, 42:60] == 0.0) and np.allclose(obs[1:, 42:60], ACTION)
    assert [c["task"][0] for c in log["/deploy/command"]][-1] == pytest.approx([0, 0, 0.5])


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
