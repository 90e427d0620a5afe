"""A run directory's life: one run at a time claims it, a killed run's leftovers do not
block or linger, and a run stopped before its first checkpoint says there is nothing to
resume. On the physics-free chain task (no compile of physics)."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import textwrap
import threading

import pytest
import yaml
from tabular_fakes import fake_envs

from jaxenvs import cli, files
from jaxenvs.run import loop, runner

CHAIN_AGENT = {
    "alpha": 0.5,
    "gamma": 0.9,
    "epsilon_discount": 0.95,
    "number_splits": 7,
    "obs_low": [0.0],
    "obs_high": [7.0],
    "num_envs": 2,
    "chunk_steps": 30,
    "total_steps": 180,  # 3 chunks
}


@pytest.fixture(scope="module", autouse=True)
def _fakes():
    with fake_envs():
        yield


def _chain(algo="qlearning"):
    return runner.resolve_config(
        "Test-Chain-v0", algo, None, CHAIN_AGENT, {"eval_episodes": 2, "video": False}
    )


def _chain_file(tmp_path, algo):
    path = tmp_path / f"{algo}.yaml"
    data = {
        "algo": algo,
        "env": {"id": "Test-Chain-v0"},
        "agent": CHAIN_AGENT,
        "train": {"eval_episodes": 2, "video": False},
    }
    path.write_text(yaml.safe_dump(data))
    return str(path)


@pytest.mark.full
def test_a_second_run_into_a_directory_in_use_is_refused_at_once(tmp_path, monkeypatch):
    """Run A is inside its first chunk when run B (another algorithm) starts into the same
    directory: B fails before touching it, naming the directory and run A."""
    out = tmp_path / "run"
    in_chunk, release = threading.Event(), threading.Event()
    real = loop._run_chunk

    def held(*args):
        in_chunk.set()
        assert release.wait(30)
        return real(*args)

    monkeypatch.setattr(loop, "_run_chunk", held)
    results = {}
    first = threading.Thread(target=lambda: results.update(a=runner.train(_chain(), out)))
    first.start()
    try:
        assert in_chunk.wait(120)
        with pytest.raises(files.DirectoryBusy) as err:
            runner.train(_chain("sarsa"), out, quiet=True)
        message = str(err.value)
        assert str(out) in message and f"pid {os.getpid()}" in message
        assert "qlearning on Test-Chain-v0" in message and "\n" not in message
    finally:
        release.set()
        first.join()
    assert results["a"]["algo"] == "qlearning" and results["a"]["finished"]
    config = yaml.safe_load((out / runner.CONFIG_FILE).read_text())
    assert config["algo"] == "qlearning"  # B wrote nothing
    assert runner.evaluate_run(out, 2)["algo"] == "qlearning"


def _hold_claim(directory):
    """A separate process that claims ``directory`` and waits; its pid."""
    code = textwrap.dedent(
        f"""
        import sys, time
        from jaxenvs import files
        with files.claim_directory({str(directory)!r}, "another run (pid holder)"):
            print("held", flush=True)
            time.sleep(600)
        """
    )
    env = dict(os.environ, PYTHONPATH=os.pathsep.join(sys.path))
    proc = subprocess.Popen([sys.executable, "-c", code], stdout=subprocess.PIPE, env=env)
    assert proc.stdout is not None and proc.stdout.readline().strip() == b"held"
    return proc


@pytest.mark.full
def test_the_command_line_names_the_directory_and_the_other_run(tmp_path, capsys):
    out = tmp_path / "run"
    holder = _hold_claim(out)
    try:
        argv = ["train", "--config", _chain_file(tmp_path, "sarsa"), "--out", str(out)]
        assert cli.main([*argv, "--quiet"]) == 2
    finally:
        holder.kill()
        holder.wait()
    captured = capsys.readouterr()
    err = captured.err.strip()
    assert err.count("\n") == 0 and str(out) in err and "another run (pid holder)" in err, err
    assert "results in" not in captured.out + captured.err
    assert not (out / runner.CHECKPOINT_FILE).exists()


@pytest.mark.full
def test_a_killed_runs_claim_and_temporaries_do_not_survive_it(tmp_path):
    """A run stopped after one chunk, then a killed process left its claim file and a
    half-written video: the resume is not blocked and removes the leftover."""
    out = tmp_path / "run"
    runner.train(_chain(), out, quiet=True, max_chunks=1)
    holder = _hold_claim(out)
    holder.send_signal(signal.SIGKILL)
    holder.wait()
    leftover = out / ".video.mp4.k1ll3d.mp4"
    leftover.write_bytes(b"\x00" * 100)
    assert (out / files.CLAIM_FILE).read_text().startswith("another run")
    summary = runner.train(runner.load_run_config(out), out, resume=True, quiet=True)
    assert summary["finished"] and summary["chunks"] == 3
    assert not leftover.exists()


def test_a_fresh_run_refuses_a_directory_holding_a_checkpoint(tmp_path):
    out = tmp_path / "run"
    runner.train(_chain(), out, quiet=True, max_chunks=1)
    before = (out / runner.CHECKPOINT_FILE).read_bytes()
    with pytest.raises(FileExistsError, match="already holds a run; use --resume"):
        runner.train(_chain("sarsa"), out, quiet=True)
    assert (out / runner.CHECKPOINT_FILE).read_bytes() == before


def test_ctrl_c_before_the_first_checkpoint_says_nothing_can_be_resumed(
    tmp_path, monkeypatch, capsys
):
    def interrupted(*args):
        raise KeyboardInterrupt

    monkeypatch.setattr(loop, "_prepare", interrupted)
    notices: list[str] = []
    with pytest.raises(KeyboardInterrupt):
        runner.train(_chain(), tmp_path / "lib", log=notices.append)
    assert notices == [
        f"interrupted before the first checkpoint: nothing to resume in {tmp_path / 'lib'}"
    ]
    out = tmp_path / "cli"
    argv = ["train", "--config", _chain_file(tmp_path, "qlearning"), "--out", str(out)]
    assert cli.main([*argv, "--quiet"]) == 130
    err = capsys.readouterr().err
    assert "nothing was saved" in err and "--resume" not in err, err
