"""Absurd input (huge or negative seeds and sizes, infinite bounds, NaN settings) is one
line naming the flag or key, from the command line, ``jaxenvs.make`` and YAML alike."""

from __future__ import annotations

import math

import pytest

import jaxenvs
from jaxenvs import cli
from jaxenvs.config import ConfigError
from jaxenvs.run import runner

HUGE = 99999999999999999999999


def _one_line_error(capsys, argv: list[str], *names: str) -> str:
    assert cli.main(argv) == 2
    out = capsys.readouterr()
    err = out.err.strip()
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
    _one_line_error(capsys, base + argv, name)
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
    _one_line_error(capsys, argv, name)


@pytest.mark.parametrize(
    ("key", "value"),
    [
        ("divergence_bound", math.inf),
        ("divergence_bound", math.nan),
        ("force", -math.inf),
        ("timestep", math.nan),
        ("episode_length", HUGE),
        ("episode_length", -(2**40)),
        ("x_threshold", 10**400),  # an int too large for a float
    ],
)
def test_make_overrides(key, value):
    with pytest.raises(ConfigError, match=f"key {key!r}") as err:
        jaxenvs.make("CartPole-v0", **{key: value})
    assert "\n" not in str(err.value)


@pytest.mark.parametrize(
    ("section", "line", "key"),
    [
        ("env", "divergence_bound: .inf", "divergence_bound"),
        ("env", "force: .nan", "force"),
        ("agent", "alpha: .nan", "alpha"),
        ("agent", "num_envs: 99999999999999999999999", "num_envs"),
        ("train", "seed: 99999999999999999999999", "seed"),
        ("train", "seed: -1", "seed"),
    ],
)
def test_yaml_values(tmp_path, capsys, section, line, key):
    path = tmp_path / "bad.yaml"
    text = "algo: qlearning\nenv:\n  id: CartPole-v0\n"
    text += f"  {line}\n" if section == "env" else f"{section}:\n  {line}\n"
    path.write_text(text)
    with pytest.raises(ConfigError, match=f"bad.yaml.*key {key!r}"):
        runner.resolve_config(None, None, path)
    _one_line_error(capsys, ["train", "--config", str(path), "--out", str(tmp_path / "r")], key)


def test_ordinary_values_still_pass():
    env = jaxenvs.make("CartPole-v0", divergence_bound=1e6, episode_length=2**31 - 1)
    assert env.config.divergence_bound == 1e6
    resolved = runner.resolve_config(
        "CartPole-v0", "qlearning", None, {"total_steps": 10**9}, {"seed": 2**31 - 1}
    )
    assert resolved.train.seed == 2**31 - 1
