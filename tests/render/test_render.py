"""Headless rendering: backend selection, frames from functional-API states, videos, CLI."""

from __future__ import annotations

import types

import imageio.v2 as imageio
import jax
import jax.numpy as jnp
import mujoco
import numpy as np
import pytest

import jaxenvs
from jaxenvs import render
from jaxenvs.cli import main

W, H = 64, 48


@pytest.fixture(scope="module")
def env():
    return jaxenvs.make("CartpoleSwingup-v0")


@pytest.fixture(scope="module")
def trajectory(env):
    """A stacked 12-step trajectory (reset state first) from a jitted scan."""

    @jax.jit
    def run(key):
        first = env.reset(key)

        def body(s, _):
            s = env.step(s, jnp.ones((1,)))
            return s, s

        _, states = jax.lax.scan(body, first, None, length=11)
        return jax.tree.map(lambda a, b: jnp.concatenate([a[None], b]), first, states)

    return run(jax.random.key(0))


def test_backend_is_selected_and_renders(env, trajectory):
    backend = render.select_gl_backend()
    assert backend in ("egl", "osmesa", "glfw", "glx")
    assert render.select_gl_backend() == backend  # cached
    # the selected backend draws the scene: a frame with content, and the pole's swing
    # changes its pixels
    first, last = (jax.tree.map(lambda x, t=t: x[t], trajectory) for t in (0, -1))
    frames = render.render_frames(env, [first, last], width=W, height=H)
    assert frames.shape == (2, H, W, 3) and frames.dtype == np.uint8
    assert all(len(np.unique(f.reshape(-1, 3), axis=0)) > 4 for f in frames)
    assert np.any(frames[0] != frames[1])


def test_no_backend_error_names_packages(monkeypatch):
    monkeypatch.setattr(render, "_selected", None)
    monkeypatch.delenv("MUJOCO_GL", raising=False)
    monkeypatch.setattr(render, "_probe_backend", lambda name: f"{name} library not found")
    with pytest.raises(render.GLBackendError) as err:
        render.select_gl_backend()
    msg = str(err.value)
    assert "MUJOCO_GL=egl: egl library not found" in msg
    assert "libegl1" in msg and "libosmesa6" in msg
    assert isinstance(err.value, OSError)  # the CLI prints it as one line


def test_requested_backend_failure_names_package(monkeypatch):
    monkeypatch.setattr(render, "_selected", None)
    monkeypatch.setenv("MUJOCO_GL", "osmesa")
    monkeypatch.setattr(render, "_activate", lambda name: None)

    def broken() -> None:
        raise RuntimeError("OSMesa library not found")

    monkeypatch.setattr(render, "_try_context", broken)
    with pytest.raises(render.GLBackendError, match="libosmesa6"):
        render.select_gl_backend()


def test_render_frames_of_stacked_trajectory(env, trajectory):
    frames = render.render_frames(env, trajectory, width=W, height=H)
    assert frames.shape == (12, H, W, 3) and frames.dtype == np.uint8
    assert frames.std() > 0  # not a blank image
    # the pole swings, so the first and last frames differ
    assert np.abs(frames[0].astype(int) - frames[-1].astype(int)).sum() > 0


def test_list_of_states_matches_stacked(env, trajectory):
    states = [jax.tree.map(lambda x, t=t: x[t], trajectory) for t in (0, 5, 11)]
    frames = render.render_frames(env, states, width=W, height=H)
    stacked = render.render_frames(env, trajectory, width=W, height=H)
    np.testing.assert_array_equal(frames, stacked[np.array([0, 5, 11])])


def test_one_env_of_a_batched_rollout(get_batched):
    benv, reset, step = get_batched("CartpoleBalance-v0", 4)
    states = [reset(jax.random.key(1))]
    for _ in range(3):
        states.append(step(states[-1], jnp.ones((4, 1))))
    batched = jax.tree.map(lambda *xs: jnp.stack(xs), *states)
    with pytest.raises(ValueError, match="select one env"):
        render.render_frames(benv, batched, width=W, height=H)
    one = jax.tree.map(lambda x: x[:, 2], batched)
    frames = render.render_frames(benv, one, width=W, height=H)
    assert frames.shape == (4, H, W, 3)


def test_cameras(env, trajectory):
    last = jax.tree.map(lambda x: x[-1], trajectory)
    side = render.render_frames(env, last, width=W, height=H)
    fixed = render.render_frames(env, last, width=W, height=H, camera="fixed")
    assert side.shape == fixed.shape == (1, H, W, 3)
    assert not np.array_equal(side, fixed)
    with pytest.raises(ValueError, match="'side', 'fixed'"):
        render.Renderer(env, W, H, camera="nope")
    with pytest.raises(ValueError, match="out of range"):
        render.Renderer(env, W, H, camera=5)


def test_model_without_camera_uses_free_camera():
    model = mujoco.MjModel.from_xml_string(
        "<mujoco><worldbody><light pos='0 0 3'/><body><freejoint/>"
        "<geom type='box' size='.2 .2 .2' rgba='1 0 0 1'/></body></worldbody></mujoco>"
    )
    fake = types.SimpleNamespace(sim=types.SimpleNamespace(mj_model=model))
    with pytest.warns(UserWarning, match="free camera"):
        renderer = render.Renderer(fake, W, H)
    with renderer:
        frame = renderer.frame(model.qpos0)
    red = (frame[..., 0] > 100) & (frame[..., 1] < 60)
    assert red.any()  # the free camera looks at the box


def test_frames_larger_than_model_buffer(env, trajectory):
    first = jax.tree.map(lambda x: x[0], trajectory)
    frames = render.render_frames(env, first, width=800, height=600)
    assert frames.shape == (1, 600, 800, 3)


def test_iter_frames_draws_the_frames_of_render_frames_one_at_a_time(env, trajectory):
    stream = render.iter_frames(env, trajectory, width=W, height=H)
    first = next(stream)
    assert first.shape == (H, W, 3) and first.dtype == np.uint8
    frames = np.stack([first, *stream])
    np.testing.assert_array_equal(frames, render.render_frames(env, trajectory, width=W, height=H))


def test_write_video_mp4_and_gif(tmp_path, env, trajectory):
    frames = render.render_frames(env, trajectory, width=W, height=H)
    mp4 = render.write_video(frames, tmp_path / "a.mp4", fps=25)
    back = np.stack(imageio.mimread(mp4))
    assert back.shape == frames.shape
    assert np.abs(back.astype(int) - frames.astype(int)).mean() < 12  # lossy codec
    gif = render.write_video(frames, tmp_path / "a.gif", fps=25)
    assert len(imageio.mimread(gif)) == len(frames)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.gif", "a.mp4"]


def test_write_video_is_atomic(tmp_path, monkeypatch):
    target = tmp_path / "v.mp4"
    target.write_bytes(b"old video")

    def fail(*args, **kwargs):
        raise OSError("disk full")

    monkeypatch.setattr(render, "_mimwrite", fail)
    frames = np.zeros((2, 8, 8, 3), np.uint8)
    with pytest.raises(OSError, match="disk full"):
        render.write_video(frames, target, fps=10)
    assert target.read_bytes() == b"old video"
    assert [p.name for p in tmp_path.iterdir()] == ["v.mp4"]


@pytest.mark.parametrize(
    "frames, path, fps, match",
    [
        (np.zeros((2, 8, 8, 3), np.uint8), "x.avi", 10, "unsupported video type"),
        (np.zeros((2, 8, 8), np.uint8), "x.mp4", 10, "shape"),
        (np.zeros((2, 8, 8, 3), np.float32), "x.mp4", 10, "uint8"),
        (np.zeros((2, 8, 8, 3), np.uint8), "x.mp4", 0, "fps"),
    ],
)
def test_write_video_rejects_bad_input(tmp_path, frames, path, fps, match):
    with pytest.raises(ValueError, match=match):
        render.write_video(frames, tmp_path / path, fps=fps)
    assert list(tmp_path.iterdir()) == []


def test_cli_render_random_actions(tmp_path, capsys):
    out = tmp_path / "cp.mp4"
    argv = ["render", "CartPole-v0", "--out", str(out), "--steps", "15"]
    assert main([*argv, "--width", str(W), "--height", str(H), "--seed", "3"]) == 0
    assert f"wrote {out} (16 frames" in capsys.readouterr().out
    frames = imageio.mimread(out)
    assert len(frames) == 16 and frames[0].shape == (H, W, 3)


@pytest.mark.parametrize(
    "extra, match",
    [
        (["--out", "/nonexistent-dir/x.mp4"], "does not exist"),
        (["--out", "x.webm"], "unsupported video type"),
        (["--out", "x.mp4", "--camera", "nope"], "unknown camera"),
        (["--out", "x.mp4", "--policy", "/nonexistent-run"], "nonexistent-run"),
    ],
)
def test_cli_render_user_errors(tmp_path, monkeypatch, capsys, extra, match):
    monkeypatch.chdir(tmp_path)
    assert main(["render", "CartPole-v0", "--steps", "2", *extra]) == 2
    err = capsys.readouterr().err
    assert match in err and len(err.strip().splitlines()) == 1
    assert list(tmp_path.iterdir()) == []


@pytest.mark.full  # trains a tiny tabular run first (~1 min of CPU)
def test_cli_render_with_a_trained_policy(tmp_path, capsys):
    from jaxenvs.run import runner

    resolved = runner.resolve_config(
        "CartPole-v0",
        "qlearning",
        None,
        dict(num_envs=2, chunk_steps=20, total_steps=80),
        dict(num_seeds=1, eval_episodes=1, video=False),
    )
    run_dir = tmp_path / "run"
    runner.train(resolved, run_dir, quiet=True)
    out = tmp_path / "policy.mp4"
    size = ["--width", str(W), "--height", str(H)]
    argv = ["render", "CartPole-v0", "--policy", str(run_dir), "--out", str(out), "--steps", "10"]
    assert main([*argv, *size]) == 0
    assert len(imageio.mimread(out)) == 11
    wrong = ["render", "CartpoleBalance-v0", "--policy", str(run_dir), "--out", str(out)]
    assert main(wrong) == 2
    assert "is a run of CartPole-v0" in capsys.readouterr().err


def _frames_of(path) -> int:
    """How many frames the video at ``path`` holds."""
    return sum(1 for _ in imageio.get_reader(str(path)))


def test_policy_video_draws_the_episode_on_its_worker(tmp_path, env, trajectory):
    """The end-of-run video: the worker makes the renderer ready before the episode comes,
    then writes every stride-th state's frame (the reset state first)."""
    from jaxenvs.run.video import PolicyVideo, video_stride

    said: list[str] = []
    video = PolicyVideo(env, tmp_path / "v.mp4", said.append)
    video.draw(jax.device_get(trajectory), 11)
    assert video.wait() == tmp_path / "v.mp4"
    assert said == []
    stride = video_stride(env)
    assert _frames_of(tmp_path / "v.mp4") == len(range(0, 12, stride))


def test_policy_video_cancelled_or_failing_writes_nothing(tmp_path, env, trajectory):
    """Cancelled (an interrupted run), the worker ends without a file; an episode it
    cannot draw (another task's states) leaves no file either, and one notice says why."""
    from jaxenvs.run.video import PolicyVideo

    said: list[str] = []
    cancelled = PolicyVideo(env, tmp_path / "c.mp4", said.append)
    cancelled.cancel()
    assert cancelled.wait() is None and not (tmp_path / "c.mp4").exists() and said == []
    other = jaxenvs.make("Reacher-v0")
    failing = PolicyVideo(other, tmp_path / "f.mp4", said.append)
    failing.draw(jax.device_get(trajectory), 11)  # CartpoleSwingup's states
    assert failing.wait() is None and not (tmp_path / "f.mp4").exists()
    assert len(said) == 1 and said[0].startswith("no video: ")
