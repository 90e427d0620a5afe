"""Headless rendering: GL backend selection, frames from functional-API states, videos.

Frames come from MuJoCo's own renderer (``mujoco.Renderer``) on the host model of a task
(``env.sim.mj_model``): a state's ``qpos`` and mocap poses are copied into a host
``MjData``, kinematics are recomputed, and the scene is drawn from the task's camera.

Camera choice, first match wins: the ``camera`` argument (name or index); the task's
``render_camera`` attribute if it has one; the model's first camera (``cartpole.xml``'s
``"side"``); otherwise a free camera looking at the model's centre (a warning says so).

GL backend: MuJoCo reads ``MUJOCO_GL`` when it is first imported, which usually happens
before anyone thinks of rendering. :func:`select_gl_backend` therefore probes the headless
backends itself (EGL, then OSMesa; only the one named in ``MUJOCO_GL`` if that is set),
each in a short subprocess so that a broken driver cannot take this process down, then
points MuJoCo's context class at the first one that works. When none works it raises
:class:`GLBackendError` naming the system packages to install.
"""

from __future__ import annotations

import contextlib
import copy
import importlib
import os
import re
import subprocess
import sys
import tempfile
import warnings
from collections.abc import Iterable, Iterator, Sequence
from pathlib import Path
from typing import Any

import mujoco
import numpy as np

from jaxenvs import files

#: headless backends tried in order when ``MUJOCO_GL`` is not set.
HEADLESS_BACKENDS = ("egl", "osmesa")

#: what to install for each backend (Debian/Ubuntu package names).
INSTALL_HINTS = {
    "egl": "EGL with a Mesa driver: apt-get install -y libegl1 libegl-mesa0 libgl1",
    "osmesa": "OSMesa: apt-get install -y libosmesa6",
    "glfw": "a display (X11/Wayland) and glfw: pip install glfw",
    "glx": "a display (X11) and libgl1",
}

_PROBE = (
    "import mujoco\n"
    'm = mujoco.MjModel.from_xml_string(\'<mujoco><worldbody><geom size="1"/></worldbody>'
    "</mujoco>')\n"
    "r = mujoco.Renderer(m, 8, 8)\n"
    "d = mujoco.MjData(m)\n"
    "mujoco.mj_forward(m, d)\n"
    "r.update_scene(d)\n"
    "r.render()\n"
    "r.close()\n"
)

_selected: str | None = None


class GLBackendError(OSError):
    """No OpenGL backend for offscreen rendering works on this machine."""


def _probe_backend(backend: str) -> str | None:
    """Try ``backend`` in a subprocess; ``None`` if it renders, else why it failed."""
    env = dict(os.environ, MUJOCO_GL=backend, PYOPENGL_PLATFORM=backend)
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)  # JAX's fork notice; we exec
            proc = subprocess.run(
                [sys.executable, "-c", _PROBE],
                env=env,
                capture_output=True,
                text=True,
                timeout=120,
                check=False,
            )
    except (OSError, subprocess.TimeoutExpired) as err:
        return f"{type(err).__name__}: {err}"
    if proc.returncode == 0:
        return None
    lines = [ln for ln in proc.stderr.strip().splitlines() if ln.strip()]
    return lines[-1] if lines else f"exit status {proc.returncode}"


def _try_context() -> None:
    """Create and free a tiny GL context in this process (raises if it cannot)."""
    model = mujoco.MjModel.from_xml_string("<mujoco/>")
    renderer = mujoco.Renderer(model, 8, 8)
    renderer.close()


def _activate(backend: str) -> None:
    """Point MuJoCo's renderer at ``backend``'s context class in this process."""
    platform = os.environ.get("PYOPENGL_PLATFORM")
    if platform and platform.lower() != backend and backend in HEADLESS_BACKENDS:
        raise GLBackendError(
            f"PYOPENGL_PLATFORM={platform!r} conflicts with the {backend!r} GL backend; "
            f"unset it or set it to {backend!r}"
        )
    os.environ["MUJOCO_GL"] = backend
    if backend in HEADLESS_BACKENDS:
        os.environ["PYOPENGL_PLATFORM"] = backend
    context_cls = importlib.import_module(f"mujoco.{backend}").GLContext
    gl_context = importlib.import_module("mujoco.rendering.classic.gl_context")
    for module in (gl_context, mujoco):
        setattr(module, "GLContext", context_cls)  # noqa: B010


def select_gl_backend() -> str:
    """Pick (once per process) a working GL backend and make MuJoCo use it.

    Returns the backend's name (``"egl"``, ``"osmesa"``, or what ``MUJOCO_GL`` names).
    Raises :class:`GLBackendError` naming what to install when none works.
    """
    global _selected
    if _selected is not None:
        return _selected
    requested = os.environ.get("MUJOCO_GL", "").strip().lower()
    if requested:  # the user chose: try it here, no probing of alternatives
        try:
            _activate(requested)
            _try_context()
        except Exception as err:  # any failure means it cannot render
            raise GLBackendError(no_backend_message([(requested, str(err))])) from err
        _selected = requested
        return requested
    failures = []
    for backend in HEADLESS_BACKENDS:
        reason = _probe_backend(backend)
        if reason is None:
            _activate(backend)
            _selected = backend
            return backend
        failures.append((backend, reason))
    raise GLBackendError(no_backend_message(failures))


def no_backend_message(failures: Sequence[tuple[str, str]]) -> str:
    """The error text when every backend in ``failures`` (name, reason) failed."""
    tried = "; ".join(f"MUJOCO_GL={name}: {reason}" for name, reason in failures)
    hints = " or ".join(INSTALL_HINTS.get(name, name) for name, _ in failures)
    return f"no OpenGL backend can render offscreen here (tried {tried}). Install {hints}."


# ------------------------------------------------------------------------------ frames
def _camera_for(model: mujoco.MjModel, env: Any, camera: str | int | None) -> Any:
    """The camera id (int) to render from, or a free ``MjvCamera`` as the fallback."""
    if camera is None:
        camera = getattr(env, "render_camera", None)
    if camera is not None:
        if isinstance(camera, str):
            cam_id = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_CAMERA, camera)
            if cam_id < 0:
                names = [model.camera(i).name for i in range(model.ncam)]
                raise ValueError(f"unknown camera {camera!r}; the model has {names}")
            return cam_id
        if not 0 <= int(camera) < model.ncam:
            raise ValueError(f"camera index {camera} out of range; the model has {model.ncam}")
        return int(camera)
    if model.ncam > 0:
        return 0
    free = mujoco.MjvCamera()
    mujoco.mjv_defaultFreeCamera(model, free)
    warnings.warn(
        f"{type(env).__name__}: the model has no camera; rendering from a free camera "
        "looking at the model's centre",
        stacklevel=3,
    )
    return free


class Renderer:
    """Draws frames of one task's states on the host.

    Args:
      env: a jaxenvs :class:`~jaxenvs.core.Env` (or a ``BatchedEnv``; its single env is
        used).
      width, height: frame size in pixels.
      camera: camera name or index; see the module docstring for the default.
    """

    def __init__(
        self, env: Any, width: int = 640, height: int = 480, camera: str | int | None = None
    ) -> None:
        env = getattr(env, "env", env)
        if width < 1 or height < 1:
            raise ValueError(f"frame size must be positive, got {width}x{height}")
        model = copy.deepcopy(env.sim.mj_model)
        model.vis.global_.offwidth = max(model.vis.global_.offwidth, int(width))
        model.vis.global_.offheight = max(model.vis.global_.offheight, int(height))
        # no multisampling: under software GL (Mesa on a CPU) a 640x480 CartPole frame
        # takes 4.0 ms without it and 11.0 ms with MuJoCo's default 4 samples (2 cores)
        model.vis.quality.offsamples = 0
        self.model = model
        self.data = mujoco.MjData(model)
        self.width, self.height = int(width), int(height)
        self.camera = _camera_for(model, env, camera)
        self._renderer: mujoco.Renderer | None = None

    def _gl(self) -> mujoco.Renderer:
        if self._renderer is None:
            select_gl_backend()
            self._renderer = mujoco.Renderer(self.model, self.height, self.width)
            # shadows and reflections are most of a frame's cost under software GL (Mesa on
            # a CPU: 156 ms a frame with them, 4 ms without, at 400x300 on 2 cores)
            flags = self._renderer.scene.flags
            flags[mujoco.mjtRndFlag.mjRND_SHADOW] = 0
            flags[mujoco.mjtRndFlag.mjRND_REFLECTION] = 0
        return self._renderer

    def frame(
        self,
        qpos: np.ndarray,
        mocap_pos: np.ndarray | None = None,
        mocap_quat: np.ndarray | None = None,
    ) -> np.ndarray:
        """One ``(height, width, 3)`` uint8 frame of the pose ``qpos`` (+ mocap poses)."""
        self.data.qpos[:] = qpos
        if mocap_pos is not None and self.model.nmocap:
            self.data.mocap_pos[:] = mocap_pos
        if mocap_quat is not None and self.model.nmocap:
            self.data.mocap_quat[:] = mocap_quat
        mujoco.mj_forward(self.model, self.data)
        renderer = self._gl()
        renderer.update_scene(self.data, camera=self.camera)
        return renderer.render()  # a new array each call

    def render_state(self, state: Any) -> np.ndarray:
        """The frame of one (unbatched) functional-API :class:`~jaxenvs.core.State`."""
        pose = _host_pose(state, self.model)
        if pose["qpos"].ndim != 1:
            raise ValueError(
                f"render_state takes one env's state; got qpos of shape {pose['qpos'].shape}"
            )
        return self.frame(**pose)

    def close(self) -> None:
        """Free the GL context; safe to call twice."""
        if self._renderer is not None:
            self._renderer.close()
            self._renderer = None

    def __enter__(self) -> Renderer:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def _host_pose(states: Any, model: mujoco.MjModel) -> dict[str, np.ndarray]:
    """qpos and mocap poses of a State (or list of States) as host arrays, one transfer each."""
    if isinstance(states, (list, tuple)):
        if not states:
            raise ValueError("no states to render")
        parts = [_host_pose(s, model) for s in states]
        return {k: np.stack([p[k] for p in parts]) for k in parts[0]}
    data = states.data
    pose = {
        "qpos": np.asarray(data.qpos, np.float64),
        "mocap_pos": np.asarray(data.mocap_pos, np.float64),
        "mocap_quat": np.asarray(data.mocap_quat, np.float64),
    }
    if pose["qpos"].shape[-1] != model.nq:
        raise ValueError(
            f"states have qpos of size {pose['qpos'].shape[-1]}, the model has nq={model.nq}"
        )
    return pose


def iter_frames(
    env: Any,
    states: Any,
    *,
    width: int = 640,
    height: int = 480,
    camera: str | int | None = None,
) -> Iterator[np.ndarray]:
    """The ``(height, width, 3)`` uint8 frames of a trajectory, drawn one at a time as
    they are taken (what :func:`write_video` streams into the encoder); the states are
    those of :func:`render_frames`, checked before the first frame is drawn."""
    renderer = Renderer(env, width, height, camera)
    pose = _host_pose(states, renderer.model)
    qpos = pose["qpos"]
    if qpos.ndim == 1:
        pose = {k: v[None] for k, v in pose.items()}
    elif qpos.ndim != 2:
        raise ValueError(
            f"expected one env's trajectory (qpos of shape (T, nq)), got {qpos.shape}; "
            "select one env of a batch with jax.tree.map(lambda x: x[:, i], states)"
        )
    return _draw(renderer, pose)


def _draw(renderer: Renderer, pose: dict[str, np.ndarray]) -> Iterator[np.ndarray]:
    with renderer:
        for t in range(pose["qpos"].shape[0]):
            yield renderer.frame(pose["qpos"][t], pose["mocap_pos"][t], pose["mocap_quat"][t])


def render_frames(
    env: Any,
    states: Any,
    *,
    width: int = 640,
    height: int = 480,
    camera: str | int | None = None,
) -> np.ndarray:
    """Render a trajectory of functional-API states to ``(T, height, width, 3)`` uint8.

    ``states`` is a list of single-env :class:`~jaxenvs.core.State` or one State whose
    leaves have a leading time axis (what ``jax.lax.scan`` returns). For a batched
    rollout pick one env first: ``jax.tree.map(lambda x: x[:, i], states)``.
    """
    return np.stack(list(iter_frames(env, states, width=width, height=height, camera=camera)))


# ------------------------------------------------------------------------------ videos
VIDEO_SUFFIXES = (".mp4", ".gif")


def check_video_path(path: str | os.PathLike[str]) -> Path:
    """``path`` as a Path if a video can be written there, else ValueError/OSError."""
    path = Path(path)
    if path.suffix.lower() not in VIDEO_SUFFIXES:
        raise ValueError(f"unsupported video type {path.suffix!r}; use one of {VIDEO_SUFFIXES}")
    if not path.parent.is_dir():
        raise OSError(f"cannot write {path}: directory {path.parent} does not exist")
    return path


class VideoError(OSError):
    """The encoder could not write a video (its own error line says why)."""


def check_video_size(path: str | os.PathLike[str], width: int, height: int) -> None:
    """ValueError unless frames of ``width`` x ``height`` can be encoded to ``path``: an
    .mp4 (H.264 in yuv420p, what every player plays) needs both even."""
    if Path(path).suffix.lower() == ".mp4" and (width % 2 or height % 2):
        raise ValueError(
            f"an .mp4 video needs an even width and height (H.264, yuv420p); got {width}x{height}"
        )


def write_video(
    frames: np.ndarray | Iterable[np.ndarray], path: str | os.PathLike[str], fps: float = 30.0
) -> Path:
    """Write ``frames`` to ``path`` (.mp4 via ffmpeg, or .gif).

    ``frames`` is a ``(T, H, W, 3)`` uint8 array (NumPy or JAX, taken whole) or an iterable
    of ``(H, W, 3)`` uint8 frames (such as :func:`iter_frames`), which an .mp4 encodes as
    they come: drawing and encoding overlap, and the video is never held whole in memory.
    Each frame must have the first one's shape and dtype; a bad first frame is refused
    before the encoder starts. An iterator with a ``close`` (a generator) is closed when
    this returns or raises.

    The file appears atomically and only when the encoder succeeded: it is written next
    to ``path`` under a temporary name and renamed into place once ffmpeg has exited
    with status 0, so a reader never sees a half-written video and a failed write
    leaves ``path`` as it was. A failing encoder (a full disk, a size it refuses) raises
    :class:`VideoError` naming ``path`` with ffmpeg's first error line (the cause). An
    .mp4 needs an even frame width and height (:func:`check_video_size`).
    """
    import imageio.v2 as imageio

    path = check_video_path(path)
    if not fps > 0:
        raise ValueError(f"fps must be positive, got {fps}")
    with _frame_stream(frames) as (first, stream):
        check_video_size(path, first.shape[1], first.shape[0])
        try:
            with files.atomic_path(path) as tmp:
                _mimwrite(imageio, str(tmp), stream, first.shape, path.suffix.lower(), fps)
        except VideoError as err:
            raise VideoError(f"cannot write {path}: {err}") from None
    return path


@contextlib.contextmanager
def _frame_stream(
    frames: np.ndarray | Iterable[np.ndarray],
) -> Iterator[tuple[np.ndarray, Iterator[np.ndarray]]]:
    """The first frame and an iterator over every frame (the first included), each checked
    against the first's shape and dtype as it is taken; ValueError for a bad first frame.
    An array (a JAX one too) is taken whole, at once. On leaving, the caller's iterator is
    closed, whatever happened (a frame generator holding a renderer lets its GL context
    go then, not when it is garbage-collected)."""
    if hasattr(frames, "__array__"):
        frames = np.asarray(frames)
        if frames.ndim != 4:
            shape = frames.shape
            raise ValueError(f"expected frames of shape (T, H, W, 3) with T > 0, got {shape}")
    it = iter(frames)
    try:
        yield _first_and_rest(it)
    finally:
        close = getattr(it, "close", None)
        if close is not None:
            close()


def _first_and_rest(it: Iterator[np.ndarray]) -> tuple[np.ndarray, Iterator[np.ndarray]]:
    first = next(it, None)
    if first is None:
        raise ValueError("expected frames of shape (T, H, W, 3) with T > 0, got no frame")
    first = np.asarray(first)
    if first.ndim != 3 or first.shape[-1] != 3:
        raise ValueError(f"expected frames of shape (H, W, 3), got one of shape {first.shape}")
    if first.dtype != np.uint8:
        raise ValueError(f"expected uint8 frames, got {first.dtype}")

    def checked() -> Iterator[np.ndarray]:
        yield first
        for t, frame in enumerate(it, start=1):
            frame = np.asarray(frame)
            if frame.shape != first.shape or frame.dtype != first.dtype:
                raise ValueError(
                    f"frame {t} is {frame.dtype} of shape {frame.shape}; "
                    f"frame 0 was {first.dtype} of shape {first.shape}"
                )
            yield frame

    return first, checked()


def _mimwrite(
    imageio: Any,
    tmp: str,
    frames: Iterator[np.ndarray],
    shape: tuple[int, ...],
    suffix: str,
    fps: float,
) -> None:
    if suffix == ".mp4":
        _encode_mp4(tmp, frames, shape, fps)
    else:
        imageio.mimwrite(tmp, list(frames), format="GIF", duration=1000.0 / fps, loop=0)


def ffmpeg_command(path: str, width: int, height: int, fps: float) -> list[str]:
    """The ffmpeg command that reads raw RGB frames on stdin and writes H.264 to ``path``."""
    import imageio_ffmpeg

    raw = ["-f", "rawvideo", "-pix_fmt", "rgb24", "-s", f"{width}x{height}"]
    # x264's "ultrafast" preset on one thread: the fewest CPU seconds a frame, which is what
    # counts while the frames are drawn and the learning curve is plotted beside it (251
    # CartPole frames at 640x480 on 2 cores: 1.1 s of ffmpeg's CPU against 1.8 s at
    # "veryfast" on its default threads; a trained policy's episode in 117 kB against 29 kB)
    out = ["-an", "-c:v", "libx264", "-preset", "ultrafast", "-threads", "1"]
    out += ["-pix_fmt", "yuv420p", "-f", "mp4"]
    exe = imageio_ffmpeg.get_ffmpeg_exe()
    return [exe, "-y", "-v", "error", *raw, "-r", f"{fps:.6g}", "-i", "-", *out, path]


def _encode_mp4(
    path: str, frames: Iterator[np.ndarray], shape: tuple[int, ...], fps: float
) -> None:
    """Pipe ``frames`` (each of ``shape``, ``(H, W, 3)``) through ffmpeg into ``path`` as
    they come; :class:`VideoError` with
    ffmpeg's first error line unless it exits with status 0 having read every frame. An
    error raised while taking a frame stops ffmpeg and propagates."""
    with tempfile.TemporaryFile() as log, warnings.catch_warnings():
        # JAX's notice about fork(); the encoder (and its probe for a working ffmpeg) is a
        # plain exec
        warnings.filterwarnings("ignore", message="os.fork", category=RuntimeWarning)
        cmd = ffmpeg_command(path, shape[1], shape[0], fps)
        proc = subprocess.Popen(cmd, stdin=subprocess.PIPE, stdout=subprocess.DEVNULL, stderr=log)
        assert proc.stdin is not None
        broken = False
        try:
            try:
                for frame in frames:
                    proc.stdin.write(np.ascontiguousarray(frame).reshape(-1).data)
            except BrokenPipeError:  # ffmpeg quit early: its exit status and log say why
                broken = True
            with contextlib.suppress(BrokenPipeError):
                proc.stdin.close()
            status = proc.wait()
        finally:
            if proc.poll() is None:  # a frame could not be taken: stop the encoder
                proc.kill()
                proc.wait()
            with contextlib.suppress(OSError):  # closed above, or a pipe ffmpeg left
                proc.stdin.close()
        if status != 0 or broken:
            log.seek(0)
            reason = first_error(log.read().decode(errors="replace"))
            raise VideoError(f"ffmpeg failed (exit status {status}): {reason}")


def first_error(log: str) -> str:
    """The first line of an ffmpeg error log (its cause; later lines are consequences),
    without the ``[component @ 0x...]`` prefixes."""
    for line in log.splitlines():
        line = re.sub(r"^(\[[^]]*\]\s*)+", "", line).strip()
        if line:
            return line
    return "it stopped reading frames without a message"
