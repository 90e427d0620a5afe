"""``jaxenvs train`` / ``eval`` / ``compare`` / ``render`` / ``bench`` and config files:
user errors are one line naming the key, flag or file (a traceback under ``--debug``)."""

from __future__ import annotations

import gc
import json
import subprocess
import sys
from importlib import resources

import pytest
import yaml
from tabular_fakes import fake_envs

from jaxenvs import cli
from jaxenvs.config import ConfigError
from jaxenvs.run import runner

CHAIN_AGENT = {
    "alpha": 0.5,
    "gamma": 0.9,
    "epsilon_discount": 0.95,
    "number_splits": 7,
    "obs_low": [0.0],
    "obs_high": [7.0],
    "num_envs": 2,
    "chunk_steps": 30,
    "total_steps": 300,
}


@pytest.fixture(scope="module", autouse=True)
def _fakes():
    with fake_envs():
        yield


def _write(path, data):
    path.write_text(yaml.safe_dump(data))
    return str(path)


def _chain_file(tmp_path, algo="sarsa", **agent):
    return _write(
        tmp_path / f"chain_{algo}.yaml",
        {
            "algo": algo,
            "env": {"id": "Test-Chain-v0", "episode_length": 12, "length": 3},
            "agent": {**CHAIN_AGENT, **agent},
            "train": {"eval_episodes": 3, "video": False},
        },
    )


@pytest.mark.parametrize(
    "section, entry, key",
    [
        ("agent", {"alphaa": 0.1}, "alphaa"),  # unknown key
        ("agent", {"alpha": "fast"}, "alpha"),  # wrong type
        ("agent", {"alpha": -0.5}, "alpha"),  # impossible value
        ("agent", {"number_splits": 0}, "number_splits"),
        ("env", {"forse": 3.0}, "forse"),
        ("train", {"num_seeds": 0}, "num_seeds"),
    ],
)
def test_bad_config_names_key_and_file(tmp_path, capsys, section, entry, key):
    data = yaml.safe_load(
        resources.files("jaxenvs.configs").joinpath("qlearning_CartPole-v0.yaml").read_text()
    )
    data[section].update(entry)
    path = _write(tmp_path / "bad.yaml", data)
    code = cli.main(["train", "CartPole-v0", "--config", path, "--out", str(tmp_path / "r")])
    err = capsys.readouterr().err
    assert code == 2
    assert key in err and path in err, err
    assert not (tmp_path / "r").exists()


def test_unknown_section_and_unsafe_yaml_are_refused(tmp_path):
    path = _write(tmp_path / "s.yaml", {"agents": {"alpha": 0.1}})
    with pytest.raises(ConfigError, match="agents"):
        runner.resolve_config("CartPole-v0", "qlearning", path)
    unsafe = tmp_path / "unsafe.yaml"
    unsafe.write_text("agent: !!python/object/apply:os.system ['echo hi']\n")
    with pytest.raises(ConfigError, match="not valid YAML"):
        runner.resolve_config("CartPole-v0", "qlearning", unsafe)


def test_command_line_overrides_file(tmp_path):
    path = _chain_file(tmp_path)
    resolved = runner.resolve_config(
        None, None, path, {"num_envs": 5, "total_steps": None}, {"seed": 9}
    )
    assert resolved.algo == "sarsa" and resolved.env_id == "Test-Chain-v0"
    assert resolved.agent.num_envs == 5 and resolved.agent.total_steps == 300
    assert resolved.train.seed == 9 and resolved.env.episode_length == 12
    with pytest.raises(ConfigError, match="not 'CartPole-v0'"):
        runner.resolve_config("CartPole-v0", None, path)


def test_shipped_configs_resolve():
    files = resources.files("jaxenvs.configs")
    names = sorted(f.name for f in files.iterdir() if f.name.endswith(".yaml"))
    assert "qlearning_CartpoleStayUp-v0.yaml" in names
    for name in names:
        stem = name.removesuffix(".yaml")
        algo, rest = stem.split("_", 1)  # <algo>_<id>.yaml or <algo>_<id>.<variant>.yaml
        env_id, _, variant = rest.partition(".")  # ids hold no dot
        if variant:  # a variant is chosen by its name: --config NAME
            resolved = runner.resolve_config(None, None, name)
        else:
            path = runner.shipped_config(algo, env_id)
            assert path is not None and path.name == name
            resolved = runner.resolve_config(None, None, path)
        assert (resolved.algo, resolved.env_id) == (algo, env_id), name
    with resources.as_file(files.joinpath("qlearning_CartpoleStayUp-v0.yaml")) as path:
        course = runner.resolve_config(None, None, path)
    env, agent = course.env, course.agent
    assert (env.n_actions, env.running_step, env.pos_step) == (4, 0.04, 0.016)
    assert (env.min_pole_angle, env.max_pole_angle) == (-0.7, 0.7)
    assert (env.min_base_pose_x, env.max_base_pose_x, env.episode_length) == (-2.5, 2.5, 1000)
    assert (agent.alpha, agent.gamma, agent.epsilon, agent.epsilon_discount) == (
        0.5,
        0.9,
        0.1,
        0.999,
    )
    assert (agent.number_splits, agent.episodes_per_env, agent.num_envs) == (10, 1000, 1)
    # without --config, the shipped file of (algo, id) is the default
    default = runner.resolve_config("CartPole-v0", "sarsa")
    assert default.agent.number_splits == (1, 1, 6, 6) and default.algo == "sarsa"


def test_missing_algorithm_module_is_reported(monkeypatch):
    monkeypatch.setitem(
        runner.ALGORITHMS, "ppo", runner.AlgoEntry("jaxenvs.agents.no_such_module", "X")
    )
    with pytest.raises(ConfigError, match="not available yet"):
        runner.resolve_config("CartPole-v0", "ppo")


@pytest.mark.full
def test_train_eval_compare(tmp_path, capsys):
    # --no-compile-cache: the tests must not switch on the persistent cache process-wide
    runs = []
    for algo in ("qlearning", "sarsa"):
        out = tmp_path / algo
        code = cli.main(
            ["train", "--config", _chain_file(tmp_path, algo), "--out", str(out)]
            + ["--quiet", "--no-compile-cache"]
        )
        assert code == 0, capsys.readouterr().err
        summary = json.loads((out / "summary.json").read_text())
        assert summary["algo"] == algo and summary["eval_mean_return"] == 1.0
        saved = yaml.safe_load((out / "config.yaml").read_text())
        assert saved["algo"] == algo and saved["agent"]["alpha"] == 0.5
        assert saved["env"]["divergence_bound"] == 1e4  # every field, defaults included
        runs.append(str(out))
    capsys.readouterr()
    assert cli.main(["eval", runs[0], "--episodes", "4", "--json"]) == 0
    result = json.loads(capsys.readouterr().out)
    assert result["episodes"] == 4 and result["mean_return"] == 1.0
    plot = tmp_path / "cmp.png"
    assert cli.main(["compare", *runs, "--out", str(plot)]) == 0
    assert plot.stat().st_size > 1000
    text = capsys.readouterr().out
    assert runs[0] in text and runs[1] in text
    # a second train into the same directory is refused; --resume with flags too
    assert cli.main(["train", "--config", _chain_file(tmp_path), "--out", runs[0]]) == 2
    assert cli.main(["train", "--resume", runs[0], "--seed", "3"]) == 2
    assert "--seed" in capsys.readouterr().err
    # resuming a finished run re-evaluates and keeps the result
    assert cli.main(["train", "--resume", runs[0], "--quiet", "--no-compile-cache"]) == 0
    assert json.loads((tmp_path / "qlearning" / "summary.json").read_text())["chunks"] == 5


# ------------------------------------------------------------- one-line errors


def _one_line_error(code, err):
    assert code == 2
    lines = [ln for ln in err.strip().splitlines() if ln.strip()]
    assert len(lines) == 1 and lines[0].startswith("jaxenvs "), err
    assert "Traceback" not in err
    return lines[0]


@pytest.mark.parametrize("kind", ["bad_id", "missing_config", "corrupt_config", "bad_out"])
def test_cli_user_errors_are_one_line(tmp_path, capsys, kind):
    out = str(tmp_path / "run")
    args = ["train", "CartPole-v0", "--algo", "qlearning", "--no-compile-cache", "--quiet"]
    expect = ""
    if kind == "bad_id":
        args[1], expect = "NoSuchEnv-v7", "NoSuchEnv-v7"
    elif kind == "missing_config":
        expect = str(tmp_path / "missing.yaml")
        args += ["--config", expect]
    elif kind == "corrupt_config":
        corrupt = tmp_path / "corrupt.yaml"
        corrupt.write_text("algo: qlearning\nagent: {alpha: [0.1\n")
        args += ["--config", str(corrupt)]
        expect = str(corrupt)
    else:
        blocker = tmp_path / "a_file"
        blocker.write_text("not a directory")
        out = str(blocker / "run")
        expect = str(blocker)
    line = _one_line_error(cli.main([*args, "--out", out]), capsys.readouterr().err)
    assert expect in line, line
    assert not (tmp_path / "run").exists()


def test_cli_debug_shows_the_traceback(tmp_path):
    with pytest.raises(ValueError, match="unknown env id 'NoSuchEnv-v7'"):
        cli.main(["--debug", "train", "NoSuchEnv-v7", "--algo", "qlearning", "--no-compile-cache"])


def test_cli_eval_of_a_broken_run_is_one_line(tmp_path, capsys):
    with fake_envs():
        resolved = runner.resolve_config(
            "Test-Chain-v0", "qlearning", None, CHAIN_AGENT, {"video": False}
        )
        run = tmp_path / "run"
        run.mkdir()
        (run / runner.CONFIG_FILE).write_text(yaml.safe_dump(resolved.to_dict()))
        ckpt = run / runner.CHECKPOINT_FILE
        ckpt.write_bytes(b"PK\x03\x04 cut short")
        line = _one_line_error(cli.main(["eval", str(run)]), capsys.readouterr().err)
        assert "truncated or corrupt" in line and str(ckpt) in line
        line = _one_line_error(cli.main(["eval", str(tmp_path)]), capsys.readouterr().err)
        assert "not a run directory" in line


@pytest.mark.full
def test_cli_error_exit_in_a_real_process(tmp_path):
    """The installed entry point: exit status 2 and no traceback on stderr."""
    proc = subprocess.run(
        [sys.executable, "-m", "jaxenvs", "train", "NoSuchEnv-v7", "--algo", "qlearning"],
        capture_output=True,
        text=True,
        timeout=300,
        cwd=tmp_path,
    )
    assert proc.returncode == 2, proc.stderr
    assert "Traceback" not in proc.stderr
    assert "jaxenvs train: error: unknown env id 'NoSuchEnv-v7'" in proc.stderr


def test_entry_returns_main_code_and_freezes_the_collector(monkeypatch):
    """The process entry (script and ``python -m``) is :func:`cli.entry`: main's exit code,
    with the objects alive once the package is imported frozen out of the collector before
    the command runs, and those alive at the end frozen for the exit."""
    from importlib.metadata import entry_points

    (script,) = entry_points(group="console_scripts", name="jaxenvs")
    assert script.value == "jaxenvs.cli:entry"
    gc.unfreeze()
    seen = []

    def main() -> int:
        seen.append(gc.get_freeze_count())
        seen.append([seen])  # a tracked object alive at the end, made after the first freeze
        return 3

    monkeypatch.setattr(cli, "main", main)
    try:
        assert cli.entry() == 3
        assert seen[0] > 0  # frozen before the command
        assert gc.get_freeze_count() > seen[0]  # and again after it
    finally:
        gc.unfreeze()


HUGE = 99999999999999999999999


def _flag_error(capsys, argv: list[str], *names: str) -> str:
    """``jaxenvs ARGV`` exits 2 with one line naming each of ``names``."""
    assert cli.main(argv) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith(f"jaxenvs {argv[0]}: error:"), err
    assert "\n" not in err and "Traceback" not in err, err
    for name in names:
        assert name in err, err
    return err


@pytest.mark.parametrize(
    ("argv", "name"),
    [
        (["--seed", str(HUGE)], "'seed'"),
        (["--seed", "-1"], "'seed'"),
        (["--num-envs", str(HUGE)], "'num_envs'"),
        (["--num-envs", "0"], "'num_envs'"),
        (["--total-steps", str(2**40)], "'total_steps'"),
        (["--num-seeds", "-3"], "'num_seeds'"),
        (["--eval-episodes", str(2**31)], "'eval_episodes'"),
        (["--devices", str(HUGE)], "--devices"),
    ],
)
def test_train_flags(capsys, tmp_path, argv, name):
    base = ["train", "CartPole-v0", "--algo", "qlearning", "--out", str(tmp_path / "r")]
    _flag_error(capsys, base + argv, name)
    assert not (tmp_path / "r").exists()


@pytest.mark.parametrize(
    ("argv", "name"),
    [
        (["eval", "DIR", "--episodes", str(HUGE)], "--episodes"),
        (["eval", "DIR", "--episodes", "0"], "--episodes"),
        (["eval", "DIR", "--seed", str(HUGE)], "--seed"),
        (["eval", "DIR", "--seed", "-5"], "--seed"),
        (["render", "CartPole-v0", "--seed", str(HUGE)], "--seed"),
        (["render", "CartPole-v0", "--steps", str(HUGE)], "--steps"),
        (["render", "CartPole-v0", "--width", "-640"], "--width"),
        (["render", "CartPole-v0", "--fps", "inf"], "--fps"),
        (["render", "CartPole-v0", "--fps", "nan"], "--fps"),
        (["bench", "--target-s", "nan"], "--target-s"),
    ],
)
def test_other_commands_flags(capsys, tmp_path, argv, name):
    argv = [str(tmp_path) if a == "DIR" else a for a in argv]
    if argv[0] == "render":
        argv += ["--out", str(tmp_path / "v.mp4")]
    _flag_error(capsys, argv, name)


def test_sigterm_stops_train_as_ctrl_c_does(tmp_path, capsys, monkeypatch):
    """SIGTERM while a chunk runs: the results so far and the "interrupted" record are
    written, the notice gives the --resume command, exit 130, and the resume finishes (it
    used to end the process at once, with no summary)."""
    import signal

    from jaxenvs.run import loop as run_loop

    real, calls = run_loop._run_chunk, {"n": 0}

    def terminated_during_second(*args, **kwargs):
        calls["n"] += 1
        if calls["n"] == 2:
            signal.raise_signal(signal.SIGTERM)
        return real(*args, **kwargs)

    class Unhandled(Exception):
        """What a SIGTERM nobody handles does here (the process would end at once)."""

    def unhandled(signum, frame):
        raise Unhandled

    monkeypatch.setattr(run_loop, "_run_chunk", terminated_during_second)
    previous = signal.signal(signal.SIGTERM, unhandled)
    out = tmp_path / "run"
    argv = ["train", "--config", _chain_file(tmp_path, "qlearning"), "--out", str(out)]
    try:
        code = cli.main([*argv, "--quiet", "--no-compile-cache"])
        assert signal.getsignal(signal.SIGTERM) is unhandled  # restored
    finally:
        signal.signal(signal.SIGTERM, previous)
    assert code == 130
    summary = json.loads((out / "summary.json").read_text())
    assert summary["interrupted"] and summary["chunks"] == 1
    assert f"continue with: jaxenvs train --resume {out}" in capsys.readouterr().err
    monkeypatch.setattr(run_loop, "_run_chunk", real)
    assert cli.main(["train", "--resume", str(out), "--quiet", "--no-compile-cache"]) == 0
    assert not json.loads((out / "summary.json").read_text())["interrupted"]
