"""The interactive viewer: ``jaxenvs view`` and the facade's ``render_mode="human"``.

Unmarked tests need no display: the one-line refusal, the slider/action mapping and the
viewer loop driven through a stand-in for MuJoCo's window (stepping the pendulum with the
engine for task logic, tests/engines.py). Tests marked ``viewer`` open real windows under a
virtual X display (Xvfb: ``apt-get install -y xvfb``) and check a screenshot:
``python -m pytest -m viewer``.
"""

from __future__ import annotations

import contextlib
import os
import shutil
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import gymnasium
import jax
import numpy as np
import pytest
from engines import TASK_LOGIC

EXAMPLE = Path(__file__).resolve().parents[2] / "examples" / "pendulum"
sys.path.insert(0, str(EXAMPLE))

import my_pendulum  # noqa: E402,F401  (registers MyPendulum-v0)

import jaxenvs  # noqa: E402
from jaxenvs.cli import main  # noqa: E402
from jaxenvs.render import viewer  # noqa: E402

ID = "MyPendulum-v0"


# ------------------------------------------------------------------ without a display
@pytest.fixture
def no_display(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.delenv("DISPLAY", raising=False)
    monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)


@pytest.mark.usefixtures("no_display")
def test_view_without_display_says_so_in_one_line(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["view", ID, "--random"]) == 2
    captured = capsys.readouterr()
    lines = captured.err.strip().splitlines()
    assert len(lines) == 1 and captured.out == ""
    assert "no display" in lines[0] and f"jaxenvs render {ID}" in lines[0]


@pytest.mark.usefixtures("no_display")
def test_human_render_mode_refused_without_display() -> None:
    with pytest.raises(ValueError, match="needs a display"):
        gymnasium.make(f"jaxenvs/{ID}", render_mode="human")
    with pytest.raises(viewer.NoDisplayError, match="jaxenvs render"):
        viewer.view(jaxenvs.make(ID), "random", steps=1)


def test_sliders_map_to_actions_and_back() -> None:
    pend = jaxenvs.make(ID)
    model = pend.sim.mj_model  # one motor, ctrlrange [-1, 1]
    for ctrl in (-1.0, -0.25, 0.0, 0.7, 1.0):
        action = viewer.sliders_to_action(pend, model, np.array([ctrl]))
        assert action.shape == (1,) and action[0] == pytest.approx(ctrl)
        np.testing.assert_allclose(viewer.action_to_sliders(pend, model, action), [ctrl])
    assert viewer.sliders_to_action(pend, model, np.array([5.0]))[0] == 1.0
    cart = jaxenvs.make("CartPole-v0")  # discrete: left end = action 0, right end = 1
    cmodel = cart.sim.mj_model
    assert int(viewer.sliders_to_action(cart, cmodel, np.array([-0.9]))) == 0
    assert int(viewer.sliders_to_action(cart, cmodel, np.array([0.8]))) == 1
    assert viewer.action_to_sliders(cart, cmodel, np.asarray(1)) is None


class FakeHandle:
    """Stands in for MuJoCo's passive viewer handle: records what the window would show
    and sets the control sliders to ``sliders``."""

    def __init__(self, model: Any, data: Any, sliders: float, max_syncs: int) -> None:
        self.model, self.data, self.sliders = model, data, sliders
        self.syncs, self.max_syncs, self.closed = 0, max_syncs, False
        self.angles: list[float] = []
        self.ctrls: list[float] = []

    def is_running(self) -> bool:
        return not self.closed and self.syncs < self.max_syncs

    def lock(self) -> contextlib.nullcontext[None]:
        return contextlib.nullcontext()

    def sync(self) -> None:
        self.syncs += 1
        self.angles.append(float(self.data.qpos[0]))
        self.ctrls.append(float(self.data.ctrl[0]))
        if self.sliders is not None:
            self.data.ctrl[:] = self.sliders  # the user holds the slider here

    def close(self) -> None:
        self.closed = True


def _run_fake(mode: str, sliders: float | None, steps: int, **kw: Any) -> FakeHandle:
    handles: list[FakeHandle] = []

    def launch(model: Any, data: Any) -> FakeHandle:
        handles.append(FakeHandle(model, data, sliders, max_syncs=steps))
        if sliders is not None:
            data.ctrl[:] = sliders
        return handles[0]

    pend = jaxenvs.make(ID, init_velocity=0.0, physics=TASK_LOGIC, **kw)
    player = viewer.view(pend, mode, steps=steps + 5, realtime=False, launch=launch)
    (handle,) = handles
    assert handle.closed and handle.syncs == steps  # stopped when the window closed
    assert player.state is not None
    return handle


@pytest.mark.full
def test_manual_mode_drives_the_actuator_from_the_sliders() -> None:
    pushed = {s: _run_fake("manual", s, steps=10) for s in (-1.0, 1.0)}
    for s, handle in pushed.items():
        assert handle.ctrls == [s] * 10  # manual mode leaves the sliders to the user
    # same seed, same start: the +1 slider turns the pendulum the other way from -1
    delta = [h.angles[-1] - h.angles[0] for h in pushed.values()]
    assert delta[1] - delta[0] > 0.05


@pytest.mark.full
def test_random_mode_shows_actions_and_resets_at_episode_end() -> None:
    handle = _run_fake("random", None, steps=25, episode_length=10)
    ctrls = np.array(handle.ctrls)
    assert np.all(np.abs(ctrls) <= 1) and len(np.unique(ctrls)) > 10  # sliders show actions
    assert handle.data.time == pytest.approx(25 % 10 * 0.05)  # the third episode's clock


@pytest.mark.full
def test_policy_mode_plays_act_fn() -> None:
    def act_fn(obs: jax.Array, key: jax.Array) -> jax.Array:
        return jax.numpy.full((1,), 0.5)

    pend = jaxenvs.make(ID, physics=TASK_LOGIC)
    handles: list[FakeHandle] = []

    def launch(model: Any, data: Any) -> FakeHandle:
        handles.append(FakeHandle(model, data, None, max_syncs=5))
        return handles[0]

    viewer.view(pend, "policy", act_fn, realtime=False, launch=launch)
    assert handles[0].ctrls == [0.5] * 5
    with pytest.raises(ValueError, match="needs act_fn"):
        viewer.Player(pend, "policy")


def test_keys_drive_a_task_that_takes_commands() -> None:
    from jaxenvs.tasks.hexapod.joystick import HexapodJoystick

    env = jaxenvs.make("HexapodJoystick-v0", physics="c")
    assert isinstance(env, HexapodJoystick) and viewer.drivable(env)
    assert not viewer.drivable(jaxenvs.make(ID, physics=TASK_LOGIC))
    handles: list[FakeHandle] = []
    up, left, comma, stop = 265, 263, 44, viewer.STOP_KEY

    def launch(model: Any, data: Any, key_callback: Any) -> FakeHandle:
        for key in (up, up, left, comma, comma, comma, comma, comma):
            key_callback(key)
        handles.append(FakeHandle(model, data, None, max_syncs=3))
        return handles[0]

    player = viewer.view(env, "random", realtime=False, launch=launch)
    low, high = env.command_range
    expected = np.array([2 * (high[0] - low[0]) / 8, high[1], (high[2] - low[2]) / 8])
    np.testing.assert_allclose(player.keys.command, expected, rtol=1e-6)  # vy held at its top
    np.testing.assert_allclose(player.state.extras.command, expected, rtol=1e-6)
    np.testing.assert_allclose(player.state.obs[-3:], expected, rtol=1e-6)
    player.keys.press(stop)
    np.testing.assert_array_equal(player.keys.command, np.zeros(3))


# ------------------------------------------------------------- under a virtual display
def _bob_pixels(image: np.ndarray) -> int:
    """Pixels of the pendulum's orange bob (rgba .9 .4 .2), shaded: proof the 3D scene
    was drawn, not just an empty window or the viewer's panels."""
    r, g, b = (image[..., i].astype(int) for i in range(3))
    return int(np.sum((r > 180) & (g > 60) & (g < 150) & (b < 90) & (r - b > 120)))


def _screenshot(display: str) -> np.ndarray:
    from PIL import ImageGrab

    return np.asarray(ImageGrab.grab(xdisplay=display).convert("RGB"))


@pytest.fixture(scope="module")
def xvfb() -> Iterator[str]:
    """A virtual X display for the module; fails (not skips) when Xvfb is missing.

    Xvfb picks a free display number itself and writes it to a pipe once it accepts
    clients (``-displayfd``), so two test processes never share a number and no test
    connects before the server is ready.
    """
    exe = shutil.which("Xvfb")
    if exe is None:
        pytest.fail("the viewer tests need Xvfb: apt-get install -y xvfb")
    read_fd, write_fd = os.pipe()
    proc = subprocess.Popen(
        [exe, "-displayfd", str(write_fd), "-screen", "0", "1024x768x24", "-nolisten", "tcp"],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
        pass_fds=(write_fd,),
    )
    os.close(write_fd)
    try:
        number = _read_display_number(read_fd, proc, timeout=20)
        yield f":{number}"
    finally:
        os.close(read_fd)
        # close this process's GLFW connection first: Xlib exits the process when its
        # server goes away under an open connection
        import glfw

        glfw.terminate()
        proc.terminate()
        proc.wait(timeout=10)


def _read_display_number(fd: int, proc: subprocess.Popen[bytes], timeout: float) -> int:
    """The display number Xvfb writes to ``fd`` (a newline-terminated decimal) when ready."""
    import select

    text = b""
    deadline = time.monotonic() + timeout
    while not text.endswith(b"\n"):
        left = deadline - time.monotonic()
        ready, _, _ = select.select([fd], [], [], max(left, 0))
        chunk = os.read(fd, 16) if ready else b""
        if not chunk:  # timed out, or Xvfb closed the pipe without a number
            pytest.fail(f"Xvfb did not start (exit code {proc.poll()})")
        text += chunk
    return int(text)


@pytest.mark.viewer
def test_view_command_opens_draws_and_closes(xvfb: str) -> None:
    blank = _screenshot(xvfb)
    assert _bob_pixels(blank) == 0
    env = dict(os.environ, DISPLAY=xvfb, PYTHONPATH=str(EXAMPLE))
    env.pop("WAYLAND_DISPLAY", None)
    cmd = [sys.executable, "-m", "jaxenvs", "view", f"my_pendulum:{ID}", "--random"]
    proc = subprocess.Popen(
        [*cmd, "--steps", "150"], env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE
    )
    best = 0
    try:
        deadline = time.monotonic() + 240
        while proc.poll() is None and time.monotonic() < deadline:
            time.sleep(0.5)
            best = max(best, _bob_pixels(_screenshot(xvfb)))
        out, err = proc.communicate(timeout=30)
    finally:
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == 0, err.decode()[-2000:]
    assert b"Traceback" not in err
    assert b"viewer closed after" in out
    assert best > 100, "no screenshot showed the pendulum"
    assert _bob_pixels(_screenshot(xvfb)) == 0  # the window is gone


@pytest.mark.viewer
def test_human_render_mode_draws_in_a_window(xvfb: str, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("DISPLAY", xvfb)
    env = gymnasium.make(f"jaxenvs/{ID}", render_mode="human")
    assert env.unwrapped.render_mode == "human"
    env.reset(seed=0)
    best = 0
    for i in range(400):  # real time: 20 s at most; the window's first frame can lag
        env.step(env.action_space.sample())
        if i % 10 == 9:
            best = max(best, _bob_pixels(_screenshot(xvfb)))
            if best > 100:
                break
    env.close()
    assert best > 100, "no screenshot showed the pendulum"
    assert _bob_pixels(_screenshot(xvfb)) == 0
