"""Input a user can get wrong, met with the library's own one-line error: config files
too large, of junk keys or not UTF-8; numpy scalars as settings; keys and states of the
wrong kind or batch given to an env."""

from __future__ import annotations

import time

import jax
import numpy as np
import pytest
import yaml

import jaxenvs
from jaxenvs import cli, config
from jaxenvs.config import ConfigError, load_yaml
from jaxenvs.core import BatchedEnv
from jaxenvs.run import run_config


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


@pytest.fixture(scope="module")
def envs():
    env = jaxenvs.make("CartPole-v0", physics="c")
    batched = BatchedEnv(env, 3)
    return env, batched, env.reset(jax.random.key(0)), batched.reset(jax.random.key(0))


@pytest.mark.parametrize(
    "call, error, words",
    [
        (lambda e, b, s, bs: e.reset(0), TypeError, "CartPole.reset: expected a PRNG key"),
        (
            lambda e, b, s, bs: e.reset(jax.random.split(jax.random.key(0), 3)),
            ValueError,
            "CartPole.reset: expected one PRNG key",
        ),
        (lambda e, b, s, bs: e.step(bs, 0), ValueError, "CartPole.step: expected one env's state"),
        (lambda e, b, s, bs: e.step({}, 0), TypeError, "CartPole.step: expected a State"),
        (lambda e, b, s, bs: b.reset(0), TypeError, "batched CartPole.reset: expected a PRNG key"),
        (
            lambda e, b, s, bs: b.step(s, np.zeros(3, np.int32)),
            ValueError,
            "batched CartPole.step: expected a state of 3 envs, got one env's state",
        ),
    ],
)
def test_the_wrong_key_or_state_gets_the_envs_own_message(envs, call, error, words):
    with pytest.raises(error) as err:
        call(*envs)
    assert str(err.value).startswith(words) and "\n" not in str(err.value)


def test_the_right_keys_and_states_still_work(envs):
    env, batched, state, batch_state = envs
    assert env.step(state, 1).time == 1
    assert batched.step(batch_state, np.ones(3, np.int32)).time.shape == (3,)
    assert env.reset(jax.random.PRNGKey(0)).obs.shape == (env.observation_size,)
    stepped = jax.vmap(env.step)(batch_state, np.ones(3, np.int32))
    assert stepped.time.shape == (3,)
