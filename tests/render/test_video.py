"""Videos: a video the encoder fails to write is never reported as written, never replaces
the target and never costs a run its results; sizes the encoder refuses are refused first.

The encoder's failures (a full disk, a size it refuses) come from a stand-in ffmpeg named by
``IMAGEIO_FFMPEG_EXE`` that fails the way ffmpeg does: an error line on stderr and a
non-zero exit status, after reading every frame (a disk full at the end) or none (a
refusal, which the writer meets as a broken pipe).
"""

from __future__ import annotations

import gc
import json
import stat
import sys
import time
import warnings

import numpy as np
import pytest

from jaxenvs import cli, render
from jaxenvs.run import runner

FULL_DISK = "[out#0/mp4 @ 0x5581] Error writing trailer: No space left on device"
REFUSED = "[libx264 @ 0x5582] width not divisible by 2 (641x481)"

FAKE_FFMPEG = """#!{python}
import sys
if {read_all}:
    sys.stdin.buffer.read()
    with open(sys.argv[-1], "wb") as f:
        f.write(b"truncated")
sys.stderr.write({line!r} + "\\n")
sys.exit({status})
"""


def _fake_ffmpeg(tmp_path, monkeypatch, line, read_all, status):
    exe = tmp_path / "fake-ffmpeg"
    exe.write_text(
        FAKE_FFMPEG.format(python=sys.executable, read_all=read_all, line=line, status=status)
    )
    exe.chmod(exe.stat().st_mode | stat.S_IXUSR)
    monkeypatch.setenv("IMAGEIO_FFMPEG_EXE", str(exe))


@pytest.fixture
def full_disk(tmp_path, monkeypatch):
    _fake_ffmpeg(tmp_path, monkeypatch, FULL_DISK, read_all=True, status=228)


@pytest.fixture
def refusing(tmp_path, monkeypatch):
    _fake_ffmpeg(tmp_path, monkeypatch, REFUSED, read_all=False, status=187)


FRAMES = np.zeros((20, 48, 64, 3), np.uint8)


def test_a_full_disk_raises_and_keeps_the_old_video(tmp_path, full_disk):
    out = tmp_path / "videos"
    out.mkdir()
    target = out / "v.mp4"
    target.write_bytes(b"old video")
    with pytest.raises(OSError) as err:
        render.write_video(FRAMES, target, fps=25)
    message = str(err.value)
    assert str(target) in message and "No space left on device" in message
    assert "\n" not in message and "0x5581" not in message
    assert target.read_bytes() == b"old video"
    assert [p.name for p in out.iterdir()] == ["v.mp4"]


def test_an_encoder_that_stops_reading_is_reported_by_its_own_words(tmp_path, refusing):
    with pytest.raises(OSError) as err:
        render.write_video(np.zeros((200, 48, 64, 3), np.uint8), tmp_path / "v.mp4", fps=25)
    message = str(err.value)
    assert "width not divisible by 2 (641x481)" in message and "Broken pipe" not in message
    assert list(tmp_path.iterdir()) == [tmp_path / "fake-ffmpeg"]


def test_the_real_encoder_writes_what_it_is_given(tmp_path):
    frames = (np.arange(20 * 48 * 64 * 3) % 251).astype(np.uint8).reshape(20, 48, 64, 3)
    path = render.write_video(frames, tmp_path / "v.mp4", fps=25)
    import imageio.v2 as imageio

    with warnings.catch_warnings():  # JAX's notice about fork(); the reader execs ffmpeg
        warnings.filterwarnings("ignore", message="os.fork", category=RuntimeWarning)
        back = np.stack(imageio.mimread(path))
    assert back.shape == frames.shape
    assert [p.name for p in tmp_path.iterdir()] == ["v.mp4"]


def test_frames_streamed_from_an_iterator_encode_the_same_video_as_an_array(tmp_path):
    frames = (np.arange(20 * 48 * 64 * 3) % 251).astype(np.uint8).reshape(20, 48, 64, 3)
    from_array = render.write_video(frames, tmp_path / "a.mp4", fps=25)
    taken: list[int] = []

    def one_at_a_time():
        for t, frame in enumerate(frames):
            taken.append(t)
            yield frame

    from_stream = render.write_video(one_at_a_time(), tmp_path / "s.mp4", fps=25)
    assert taken == list(range(20))
    assert from_stream.read_bytes() == from_array.read_bytes()


@pytest.mark.parametrize(
    "bad, match",
    [
        (np.zeros((48, 62, 3), np.uint8), r"frame 3 .*\(48, 62, 3\)"),
        (np.zeros((48, 64, 3)), "float"),
    ],
)
def test_a_bad_frame_part_way_stops_the_encoder_and_writes_nothing(tmp_path, bad, match):
    target = tmp_path / "v.mp4"
    target.write_bytes(b"old video")
    stream = [*FRAMES[:3], bad, *FRAMES[3:]]
    with pytest.raises(ValueError, match=match):
        render.write_video(iter(stream), target, fps=25)
    assert target.read_bytes() == b"old video"
    assert [p.name for p in tmp_path.iterdir()] == ["v.mp4"]


def test_the_callers_frame_generator_is_closed_when_a_write_fails(tmp_path):
    # a generator drawing frames holds a renderer (a GL context) until it is closed; the
    # error's traceback, kept here, would otherwise keep it open
    closed: list[int] = []

    def frames(bad_at):
        try:
            for t in range(5):
                yield np.zeros((49 if t == bad_at else 48, 64, 3), np.uint8)
        finally:
            closed.append(bad_at)

    with pytest.raises(ValueError, match="frame 2") as part_way:
        render.write_video(frames(bad_at=2), tmp_path / "v.mp4", fps=25)
    with pytest.raises(ValueError, match="even width and height") as first:
        render.write_video(frames(bad_at=0), tmp_path / "v.mp4", fps=25)
    assert closed == [2, 0]
    assert part_way.value is not None and first.value is not None


def test_an_encoder_gone_before_the_frames_fail_leaves_no_pipe_open(tmp_path, monkeypatch):
    """The encoder exits after the first frame reached it (its first byte read: the
    9 kB frame is all in the pipe by then), then the frames fail: their error surfaces,
    and no pipe, warning or file is left. (An encoder that exited before the first frame
    was written would fail the write itself, a VideoError: a race this test once lost
    under load.)"""
    gone = tmp_path / "gone"
    exe = tmp_path / "fake-ffmpeg"
    exe.write_text(f"#!/bin/sh\nhead -c 1 >/dev/null\ntouch {gone}\nexit 3\n")
    exe.chmod(exe.stat().st_mode | stat.S_IXUSR)
    monkeypatch.setenv("IMAGEIO_FFMPEG_EXE", str(exe))

    def frames():
        yield FRAMES[0]
        deadline = time.monotonic() + 30
        while not gone.exists() and time.monotonic() < deadline:
            time.sleep(0.01)
        time.sleep(0.2)  # the encoder has exited by now
        raise RuntimeError("the renderer died")

    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        with pytest.raises(RuntimeError, match="the renderer died"):
            render.write_video(frames(), tmp_path / "v.mp4", fps=25)
        gc.collect()
    assert gone.exists()
    assert not [w for w in caught if issubclass(w.category, ResourceWarning)]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["fake-ffmpeg", "gone"]


def test_a_jax_array_of_frames_is_taken_whole(tmp_path):
    import jax.numpy as jnp

    frames = jnp.asarray(FRAMES)
    assert render.write_video(frames, tmp_path / "j.mp4", fps=25).read_bytes() == (
        render.write_video(FRAMES, tmp_path / "n.mp4", fps=25).read_bytes()
    )
    with pytest.raises(ValueError, match=r"\(T, H, W, 3\) with T > 0, got \(48, 64, 3\)"):
        render.write_video(frames[0], tmp_path / "one.mp4", fps=25)


def test_an_empty_stream_is_refused(tmp_path):
    with pytest.raises(ValueError, match="no frame"):
        render.write_video(iter([]), tmp_path / "v.mp4", fps=25)
    assert list(tmp_path.iterdir()) == []


def test_an_odd_size_mp4_is_refused_before_encoding(tmp_path):
    with pytest.raises(ValueError, match=r"even width and height .* 65x49"):
        render.write_video(np.zeros((2, 49, 65, 3), np.uint8), tmp_path / "v.mp4", fps=25)
    render.write_video(np.zeros((2, 49, 65, 3), np.uint8), tmp_path / "v.gif", fps=25)


@pytest.mark.parametrize("flag, size", [("--width", ["641", "480"]), ("--height", ["640", "481"])])
def test_render_refuses_an_odd_mp4_size_naming_the_flag(tmp_path, capsys, flag, size):
    argv = ["render", "CartPole-v0", "--out", str(tmp_path / "x.mp4"), "--steps", "3"]
    assert cli.main([*argv, "--width", size[0], "--height", size[1]]) == 2
    err = capsys.readouterr().err.strip()
    assert flag in err and "even" in err and "\n" not in err, err
    assert list(tmp_path.iterdir()) == []


@pytest.fixture(scope="module")
def cartpole_run(tmp_path_factory):
    out = tmp_path_factory.mktemp("run")
    agent = {"num_envs": 4, "chunk_steps": 100, "total_steps": 400}
    resolved = runner.resolve_config(
        "CartPole-v0", "qlearning", None, agent, {"eval_episodes": 1, "video": False}
    )
    runner.train(runner.with_physics(resolved, "c"), out, quiet=True)
    return out


@pytest.mark.full
def test_eval_says_the_video_failed_and_exits_non_zero(cartpole_run, tmp_path, full_disk, capsys):
    video = tmp_path / "policy.mp4"
    argv = ["eval", str(cartpole_run), "--episodes", "1", "--video", str(video)]
    assert cli.main(argv) == 1
    captured = capsys.readouterr()
    assert "return" in captured.out and "video:" not in captured.out
    err = captured.err.strip()
    assert "No space left on device" in err and str(video) in err and "\n" not in err, err
    assert not video.exists()
    assert cli.main([*argv, "--json"]) == 1
    result = json.loads(capsys.readouterr().out)
    assert result["video"] is None and "No space left on device" in result["video_error"]


def test_train_keeps_its_results_when_the_video_fails(tmp_path, full_disk):
    out = tmp_path / "run"
    agent = {"num_envs": 4, "chunk_steps": 100, "total_steps": 400}
    resolved = runner.resolve_config(
        "CartPole-v0", "qlearning", None, agent, {"eval_episodes": 1, "video": True}
    )
    notices: list[str] = []
    summary = runner.train(runner.with_physics(resolved, "c"), out, log=notices.append)
    assert summary["finished"]
    assert any("No space left on device" in n for n in notices), notices
    names = sorted(p.name for p in out.iterdir() if p.name != ".claim")
    assert names == sorted(
        [
            runner.CONFIG_FILE,
            runner.PROGRESS_FILE,
            runner.SUMMARY_FILE,
            runner.CHECKPOINT_FILE,
            runner.CURVE_FILE,
        ]
    )
    assert runner.evaluate_run(out, 1)["episodes"] == 1
