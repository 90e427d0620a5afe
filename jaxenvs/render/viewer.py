"""Interactive viewing: MuJoCo's own viewer window showing a jaxenvs task as it runs.

The task still runs as JAX (jitted ``reset``/``step`` of one env on the default device);
after every control step its state is copied into a host ``MjData`` that MuJoCo's
passive viewer (``mujoco.viewer.launch_passive``) draws. Three ways to choose actions:

* ``"manual"``: the viewer's Control sliders (right panel) are the actions. Each slider
  spans its actuator's ``ctrlrange``, which is mapped linearly onto the action range
  [-1, 1]; a discrete task reads its action from the first slider (left end = action
  0, right end = the last action).
* ``"random"``: uniform random actions.
* ``"policy"``: a trained policy, ``act_fn(obs, key) -> action`` (see
  :func:`jaxenvs.run.runner.load_policy`).

A task that takes commands (it has ``with_command(state, command)`` and
``command_range``, e.g. ``HexapodJoystick-v0``) is driven from the keyboard in every
mode: :class:`CommandKeys` (Up/Down, Left/Right, ``,``/``.`` step the command's first,
third and second entries by an eighth of their range; Backspace zeroes it), set before
every step.

In every mode a finished episode (terminated or truncated) starts again from a fresh
random initial state. In the random and policy modes the sliders show the applied
controls. Mouse perturbations in the viewer have no effect: the physics is JAX's. On a
terrain (a model with a heightfield) the camera tracks the robot (:func:`follow_robot`).

A display is needed (X11 or Wayland): :func:`require_display` raises
:class:`NoDisplayError` with a one-line message that points to ``jaxenvs render``.
"""

from __future__ import annotations

import copy
import functools
import importlib
import os
import threading
import time
from collections.abc import Callable
from typing import Any

import jax
import jax.numpy as jnp
import mujoco
import numpy as np

from jaxenvs.core import Env, State
from jaxenvs.core.xla import jit

MODES = ("manual", "random", "policy")
ActFn = Callable[[jax.Array, jax.Array], jax.Array]


class NoDisplayError(OSError):
    """The interactive viewer needs a display and none was found."""


def display_available() -> bool:
    """True when an X11 or Wayland display is named in the environment."""
    return bool(os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY"))


def no_display_message(env_id: str = "ID") -> str:
    return (
        "no display found (DISPLAY and WAYLAND_DISPLAY are unset), so the interactive "
        f"viewer cannot open; for a video use: jaxenvs render {env_id} --out video.mp4"
    )


def require_display(env_id: str = "ID") -> None:
    """Raise :class:`NoDisplayError` (one line) when there is no display."""
    if not display_available():
        raise NoDisplayError(no_display_message(env_id))


# ------------------------------------------------------------------ sliders <-> actions
def _ctrl_limits(model: mujoco.MjModel) -> tuple[np.ndarray, np.ndarray]:
    """Per-actuator slider range: ``ctrlrange`` where limited, else [-1, 1]."""
    lo, hi = -np.ones(model.nu), np.ones(model.nu)
    limited = np.asarray(model.actuator_ctrllimited, bool)
    lo[limited], hi[limited] = model.actuator_ctrlrange[limited].T
    return lo, hi


def sliders_to_action(env: Env, model: mujoco.MjModel, ctrl: np.ndarray) -> np.ndarray:
    """The action the viewer's control sliders ``ctrl`` stand for (see the module doc)."""
    lo, hi = _ctrl_limits(model)
    span = np.where(hi > lo, hi - lo, 1.0)
    unit = np.clip(2.0 * (np.asarray(ctrl, np.float64) - lo) / span - 1.0, -1.0, 1.0)
    if env.discrete:
        first = unit[0] if unit.size else 0.0
        return np.asarray(round((first + 1.0) / 2.0 * (env.action_size - 1)), np.int32)
    action = np.zeros(env.action_size, np.float32)
    n = min(env.action_size, unit.size)
    action[:n] = unit[:n]
    return action


def action_to_sliders(env: Env, model: mujoco.MjModel, action: np.ndarray) -> np.ndarray | None:
    """Slider positions showing a continuous ``action``; ``None`` for discrete tasks."""
    if env.discrete:
        return None
    lo, hi = _ctrl_limits(model)
    ctrl = np.zeros(model.nu)
    n = min(env.action_size, model.nu)
    unit = np.clip(np.asarray(action, np.float64)[:n], -1.0, 1.0)
    ctrl[:n] = lo[:n] + (unit + 1.0) / 2.0 * (hi[:n] - lo[:n])
    return ctrl


def copy_state(model: mujoco.MjModel, data: mujoco.MjData, state: State, dt: float) -> None:
    """Write one env's ``state`` (positions, velocities, mocap poses) into host ``data``."""
    mj = state.data
    data.qpos[:] = np.asarray(mj.qpos)
    data.qvel[:] = np.asarray(mj.qvel)
    if model.nmocap:
        data.mocap_pos[:] = np.asarray(mj.mocap_pos)
        data.mocap_quat[:] = np.asarray(mj.mocap_quat)
    data.time = float(state.time) * dt
    mujoco.mj_forward(model, data)


# ----------------------------------------------------------------------------- commands
#: GLFW key code -> (command entry, direction) of :class:`CommandKeys`
DRIVE_KEYS = {265: (0, 1), 264: (0, -1), 263: (2, 1), 262: (2, -1), 44: (1, 1), 46: (1, -1)}
STOP_KEY = 259  # Backspace


class CommandKeys:
    """A drivable task's command, set from the keyboard (:data:`DRIVE_KEYS`): each press
    moves one entry by an eighth of its range, within the range; :data:`STOP_KEY` zeroes
    the command. Starts at zero."""

    def __init__(self, low: np.ndarray, high: np.ndarray) -> None:
        self.low, self.high = np.asarray(low, np.float32), np.asarray(high, np.float32)
        self.increment = (self.high - self.low) / 8
        self.command = np.zeros_like(self.low)

    def press(self, keycode: int) -> None:
        """The viewer's key callback."""
        if keycode == STOP_KEY:
            self.command = np.zeros_like(self.low)
        elif keycode in DRIVE_KEYS:
            entry, direction = DRIVE_KEYS[keycode]
            command = self.command.copy()
            command[entry] = np.clip(
                command[entry] + direction * self.increment[entry],
                self.low[entry],
                self.high[entry],
            )
            self.command = command


def drivable(env: Env) -> bool:
    """Whether ``env`` takes commands (``with_command`` and ``command_range``)."""
    return callable(getattr(env, "with_command", None)) and hasattr(env, "command_range")


# ------------------------------------------------------------------------------ player
class Player:
    """One env stepped on the host's behalf: jitted reset/step, actions per mode, and a
    fresh reset whenever an episode ends.

    Args:
      env: the single env.
      mode: one of :data:`MODES`.
      act_fn: ``act_fn(obs, key) -> action`` for ``"policy"``.
      seed: seeds the reset keys and the random/policy action keys.
    """

    def __init__(self, env: Env, mode: str, act_fn: ActFn | None = None, seed: int = 0) -> None:
        if mode not in MODES:
            raise ValueError(f"unknown viewer mode {mode!r}; choose from {', '.join(MODES)}")
        if mode == "policy" and act_fn is None:
            raise ValueError("the policy mode needs act_fn")
        self.env, self.mode = env, mode
        self._reset = jit(env.reset)
        self._step = jit(env.step)
        self._act = jit(act_fn if act_fn is not None else self._random_action)
        self._key = jax.random.key(seed)
        self.episodes = 0
        #: the keyboard's command of a drivable task (else ``None``)
        self.keys = CommandKeys(*env.command_range) if drivable(env) else None  # type: ignore[attr-defined]
        self._command = jit(env.with_command) if self.keys else None  # type: ignore[attr-defined]
        self.state = self.reset()
        self.action: np.ndarray = np.zeros(env.action_shape, np.int32 if env.discrete else float)

    def _random_action(self, obs: jax.Array, key: jax.Array) -> jax.Array:
        del obs
        if self.env.discrete:
            return jax.random.randint(key, (), 0, self.env.action_size)
        return jax.random.uniform(key, (self.env.action_size,), minval=-1.0, maxval=1.0)

    def _next_key(self) -> jax.Array:
        self._key, key = jax.random.split(self._key)
        return key

    def reset(self) -> State:
        self.state = self._reset(self._next_key())
        self.episodes += 1
        return self.state

    def step(self, sliders: np.ndarray) -> State:
        """One control step; ``sliders`` (the viewer's ctrl) is used in manual mode."""
        if self.keys is not None and self._command is not None:
            self.state = self._command(self.state, jnp.asarray(self.keys.command))
        if self.mode == "manual":
            action = jnp.asarray(sliders_to_action(self.env, self.env.sim.mj_model, sliders))
        else:
            action = self._act(self.state.obs, self._next_key())
        self.action = np.asarray(action)
        self.state = self._step(self.state, action)
        if bool(self.state.terminated | self.state.truncated):
            self.reset()
        return self.state


# ------------------------------------------------------------------------------ viewer
def _passive_launcher() -> Callable[..., Any]:
    """``mujoco.viewer.launch_passive``, once a display is known to exist."""
    require_display()
    return importlib.import_module("mujoco.viewer").launch_passive


def _launch(launch: Callable[..., Any], model: mujoco.MjModel, data: mujoco.MjData) -> Any:
    """``launch(model, data)``, remembering the threads it starts on the handle.

    MuJoCo's passive viewer draws from daemon threads that tear the window down after
    ``close()`` returns; a process that exits meanwhile can crash, so :func:`_close`
    waits for them.
    """
    before = set(threading.enumerate())
    handle = launch(model, data)
    handle_threads = [t for t in threading.enumerate() if t not in before]
    return handle, handle_threads


def follow_robot(handle: Any, model: mujoco.MjModel) -> None:
    """On a terrain (a model with a heightfield: its tiles lie metres from the world's
    centre, where the free camera looks) make the viewer's camera track the robot's root
    (the first body with a free joint), 1.5 m away, 25 degrees above; elsewhere leave the
    free camera."""
    free = np.flatnonzero(model.jnt_type == mujoco.mjtJoint.mjJNT_FREE)
    if model.nhfield == 0 or free.size == 0:
        return
    with handle.lock():
        handle.cam.type = mujoco.mjtCamera.mjCAMERA_TRACKING
        handle.cam.trackbodyid = int(model.jnt_bodyid[free[0]])
        handle.cam.distance, handle.cam.elevation = 1.5, -25.0


def _close(handle: Any, threads: list[threading.Thread], timeout: float = 10.0) -> None:
    handle.close()
    deadline = time.monotonic() + timeout
    for thread in threads:
        thread.join(max(0.0, deadline - time.monotonic()))


def view(
    env: Env,
    mode: str = "manual",
    act_fn: ActFn | None = None,
    seed: int = 0,
    steps: int | None = None,
    realtime: bool = True,
    launch: Callable[..., Any] | None = None,
) -> Player:
    """Open the viewer on ``env`` and run until the window closes (or ``steps`` steps).

    ``launch`` defaults to ``mujoco.viewer.launch_passive`` (it is a parameter so the
    loop can be exercised without a window). Returns the :class:`Player` (its
    ``state``, ``episodes``).
    """
    if launch is None:
        launch = _passive_launcher()
    model = copy.deepcopy(env.sim.mj_model)
    data = mujoco.MjData(model)
    player = Player(env, mode, act_fn, seed)
    dt = env.control_dt
    copy_state(model, data, player.state, dt)
    if player.keys is not None:
        launch = functools.partial(launch, key_callback=player.keys.press)
    handle, threads = _launch(launch, model, data)
    follow_robot(handle, model)
    try:
        done = 0
        while handle.is_running() and (steps is None or done < steps):
            start = time.perf_counter()
            with handle.lock():
                sliders = data.ctrl.copy()
            state = player.step(sliders)
            with handle.lock():
                copy_state(model, data, state, dt)
                shown = action_to_sliders(env, model, player.action)
                if mode != "manual" and shown is not None:
                    data.ctrl[:] = shown
            handle.sync()
            done += 1
            if realtime:
                time.sleep(max(0.0, dt - (time.perf_counter() - start)))
    finally:
        _close(handle, threads)
    return player


class StateViewer:
    """A viewer window that shows the states pushed to it, in real time: the Gymnasium
    facade's ``render_mode="human"``. Closing the window stops the drawing, not the env.
    """

    def __init__(self, env: Env, launch: Callable[..., Any] | None = None) -> None:
        if launch is None:
            launch = _passive_launcher()
        self.env = env
        self.model = copy.deepcopy(env.sim.mj_model)
        self.data = mujoco.MjData(self.model)
        self._handle, self._threads = _launch(launch, self.model, self.data)
        follow_robot(self._handle, self.model)
        self._last = 0.0

    def show(self, state: State) -> None:
        handle = self._handle
        if handle is None or not handle.is_running():
            return
        with handle.lock():
            copy_state(self.model, self.data, state, self.env.control_dt)
        wait = self._last + self.env.control_dt - time.perf_counter()
        if wait > 0:
            time.sleep(wait)
        handle.sync()
        self._last = time.perf_counter()

    def close(self) -> None:
        if self._handle is not None:
            _close(self._handle, self._threads)
            self._handle = None
