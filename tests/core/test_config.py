"""Configs (``jaxenvs.config``, a run's YAML): absurd values (huge or negative seeds and
sizes, infinite bounds, NaN settings), unsafe or oversized files, junk keys and numpy
scalars each get one line naming the key and the file, from ``jaxenvs.make`` and YAML
alike. The command line's own flags: tests/test_cli.py."""

from __future__ import annotations

import math
import re
import time

import numpy as np
import pytest
import yaml

import jaxenvs
from jaxenvs import cli, config
from jaxenvs.config import ConfigError, load_yaml
from jaxenvs.run import run_config, runner

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


def test_python_object_yaml_is_rejected_and_never_executed(tmp_path):
    sentinel = tmp_path / "executed"
    bad = tmp_path / "evil.yaml"
    bad.write_text(
        f"algo: qlearning\nagent: !!python/object/apply:os.system ['touch {sentinel}']\n"
    )
    with pytest.raises(ConfigError, match=re.escape(str(bad))):
        load_yaml(bad)
    with pytest.raises(ConfigError, match="not valid YAML"):
        runner.resolve_config("CartPole-v0", None, bad)
    obj = tmp_path / "obj.yaml"
    obj.write_text("env: !!python/object:pathlib.PurePosixPath {}\n")
    with pytest.raises(ConfigError, match="not valid YAML"):
        load_yaml(obj)
    assert not sentinel.exists()


@pytest.mark.parametrize(
    "overrides, key",
    [
        ({"episode_length": 0}, "episode_length"),
        ({"divergence_bound": -1.0}, "divergence_bound"),
        ({"episode_length": 2.5}, "episode_length"),
        ({"divergence_bound": "big"}, "divergence_bound"),
    ],
)
def test_env_config_errors_name_key_and_file(tmp_path, overrides, key):
    path = tmp_path / "cfg.yaml"
    path.write_text(
        yaml.safe_dump({"algo": "qlearning", "env": {"id": "CartPole-v0", **overrides}})
    )
    with pytest.raises(ConfigError) as err:
        runner.resolve_config(None, None, path)
    assert key in str(err.value) and str(path) in str(err.value)


def test_flag_errors_name_the_command_line():
    with pytest.raises(ConfigError, match="command line.*num_envs"):
        runner.resolve_config("CartPole-v0", "qlearning", None, {"num_envs": 0})
    with pytest.raises(ConfigError, match="command line.*seed"):
        runner.resolve_config("CartPole-v0", "qlearning", None, None, {"seed": -1})


def test_a_config_file_over_the_limit_is_refused_before_parsing(tmp_path):
    path = tmp_path / "big.yaml"
    path.write_text("agent:\n" + "".join(f"  junk_{i}: {i}\n" for i in range(120_000)))
    assert path.stat().st_size > config.MAX_CONFIG_BYTES
    start = time.perf_counter()
    with pytest.raises(ConfigError) as err:
        load_yaml(path)
    assert time.perf_counter() - start < 1.0
    message = str(err.value)
    assert str(path) in message and str(config.MAX_CONFIG_BYTES) in message


@pytest.mark.full
def test_junk_keys_are_named_a_few_at_a_time(tmp_path, capsys):
    path = tmp_path / "junk.yaml"
    junk = {f"junk_key_{i:05d}": i for i in range(20_000)}
    path.write_text(
        yaml.safe_dump({"algo": "qlearning", "env": {"id": "CartPole-v0"}, "agent": junk})
    )
    assert path.stat().st_size < config.MAX_CONFIG_BYTES
    argv = ["train", "--config", str(path), "--out", str(tmp_path / "run"), "--quiet"]
    start = time.perf_counter()
    assert cli.main(argv) == 2
    assert time.perf_counter() - start < 20.0
    err = capsys.readouterr().err.strip()
    assert "\n" not in err and len(err) < 1000, err[:2000]
    assert "'junk_key_00000'" in err and "and 19995 more" in err and str(path) in err


def test_unknown_sections_are_named_a_few_at_a_time(tmp_path):
    path = tmp_path / "sections.yaml"
    path.write_text(yaml.safe_dump({f"section_{i}": 1 for i in range(50)} | {"algo": "sarsa"}))
    with pytest.raises(ConfigError, match="and 45 more") as err:
        run_config.resolve_config("CartPole-v0", None, path)
    assert len(str(err.value)) < 500


def test_a_config_file_that_is_not_utf8_is_named(tmp_path, capsys):
    path = tmp_path / "latin1.yaml"
    path.write_bytes("agent:\n  alpha: 0.1  # caf\u00e9\n".encode("latin-1"))
    with pytest.raises(ConfigError, match="not UTF-8") as err:
        load_yaml(path)
    assert str(path) in str(err.value)
    argv = ["train", "CartPole-v0", "--algo", "sarsa", "--config", str(path), "--quiet"]
    assert cli.main([*argv, "--out", str(tmp_path / "run")]) == 2
    assert str(path) in capsys.readouterr().err


def test_numpy_scalars_are_plain_numbers_but_numpy_bools_are_not_integers():
    env = jaxenvs.make("Reacher-v0", physics="c", episode_length=np.int64(20))
    assert env.config.episode_length == 20 and type(env.config.episode_length) is int
    env = jaxenvs.make("CartPole-v0", physics="c", force=np.float32(8.0))
    assert env.config.force == 8.0 and type(env.config.force) is float
    env = jaxenvs.make("CartPole-v0", physics="c", force=np.int32(8))
    assert type(env.config.force) is float
    with pytest.raises(ConfigError, match="expects an integer"):
        jaxenvs.make("Reacher-v0", physics="c", episode_length=np.bool_(True))
