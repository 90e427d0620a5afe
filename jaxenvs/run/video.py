"""The end-of-run video, drawn on a thread of its own.

A run's video shows its final policy, so it cannot be drawn before training ends, but
what it needs besides the episode can be made ready while the chunks run, when the host
mostly waits on the compiled program: the GL backend (probed in a subprocess), the GL
context and the encoder. Then, once the episode is handed over, the frames are drawn
and encoded while the caller writes the summary and the learning curve.
"""

from __future__ import annotations

import importlib
import queue
import threading
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import jax
import numpy as np

from jaxenvs.core import Env

#: the end-of-run video: frames per simulated second (at most) and (width, height)
VIDEO_FPS, VIDEO_SIZE = 25.0, (640, 480)


def video_stride(env: Env) -> int:
    """Every how many control steps a frame is taken: at most :data:`VIDEO_FPS` frames
    a second of simulated time."""
    return max(1, round(1.0 / (env.control_dt * VIDEO_FPS)))


class PolicyVideo:
    """One episode's video, drawn on a worker thread (see the module docstring).

    Made when training starts: the worker prepares the renderer and waits. :meth:`draw`
    hands it one env's episode (stacked States, reset state first, already on the host:
    NumPy leaves) and returns at once; :meth:`wait` returns the video's path, or ``None``
    when rendering is not available or failed, and then ``say`` gets one line saying why
    (from the caller's thread, in :meth:`wait`). :meth:`cancel` lets the worker go
    without a video (an interrupted run). The worker touches no JAX array, only a copy of
    the MuJoCo model and the host arrays it is given.
    """

    def __init__(self, env: Env, path: Path, say: Callable[[str], None]) -> None:
        self._env, self._path, self._say = env, Path(path), say
        self._episodes: queue.Queue[tuple[Any, int] | None] = queue.Queue(maxsize=1)
        self._written: Path | None = None
        self._notice: str | None = None
        self._thread = threading.Thread(target=self._work, name="policy-video", daemon=True)
        self._thread.start()

    def draw(self, trajectory: Any, length: int) -> None:
        """Hand over the episode: ``trajectory`` holds ``length + 1`` States or more."""
        self._episodes.put((trajectory, int(length)))

    def cancel(self) -> None:
        """No video: the worker frees its renderer and ends."""
        self._episodes.put(None)
        self._thread.join()

    def wait(self) -> Path | None:
        """The video's path once written (``None`` if not; ``say`` was told why)."""
        self._thread.join()
        if self._notice is not None:
            self._say(self._notice)
            self._notice = None
        return self._written

    def _work(self) -> None:
        try:
            render = importlib.import_module("jaxenvs.render")
            render.select_gl_backend()
            renderer = render.Renderer(self._env, *VIDEO_SIZE)
            renderer.frame(np.asarray(renderer.model.qpos0))  # opens the GL context
        except Exception as err:  # noqa: BLE001 - the video is optional
            self._notice = f"no video: rendering is not available ({_first_line(err)})"
            return
        with renderer:
            episode = self._episodes.get()
            if episode is None:
                return
            stride = video_stride(self._env)
            try:
                frames = _frames(renderer, *episode, stride)
                fps = 1.0 / (self._env.control_dt * stride)
                self._written = render.write_video(frames, self._path, fps=fps)
            except Exception as err:  # noqa: BLE001 - the video is optional
                self._notice = f"no video: {_first_line(err)}"


def write_policy_video(
    env: Env, trajectory: Any, length: int, path: Path, say: Callable[[str], None]
) -> Path | None:
    """Render one episode (stacked States, reset state first) to ``path`` and wait for it:
    :class:`PolicyVideo` without the head start. Rendering is optional: when
    :mod:`jaxenvs.render` is missing or fails (no GL backend, no ffmpeg), ``say`` gets a
    one-line notice and ``None`` is returned."""
    video = PolicyVideo(env, path, say)
    video.draw(jax.device_get(trajectory), length)
    return video.wait()


def _frames(renderer: Any, trajectory: Any, length: int, stride: int) -> Iterator[np.ndarray]:
    data = trajectory.data
    take = slice(0, length + 1, stride)
    qpos = np.asarray(data.qpos, np.float64)[take]
    mocap_pos = np.asarray(data.mocap_pos, np.float64)[take]
    mocap_quat = np.asarray(data.mocap_quat, np.float64)[take]
    for t in range(qpos.shape[0]):
        yield renderer.frame(qpos[t], mocap_pos[t], mocap_quat[t])


def _first_line(err: BaseException) -> str:
    text = str(err)
    return text.splitlines()[0] if text else type(err).__name__
