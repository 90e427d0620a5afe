"""Hardening against bad input: actions, configs, YAML, the command line, checkpoints.

Complements tests/test_core.py (eager shape/dtype errors, NaN and 1e9 on one env, one
diverged env isolated), tests/test_cli.py (bad config keys name key and file),
tests/test_gymnasium.py (facade errors, close twice) and tests/test_runner.py (corrupt,
truncated and foreign checkpoints). One env program is compiled for the session.
"""

from __future__ import annotations

import json
import os
import re
import subprocess
import sys
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pytest
import yaml
from tabular_fakes import fake_envs

from jaxenvs import cli, files
from jaxenvs.config import ConfigError, load_yaml
from jaxenvs.run import checkpoint, runner
from jaxenvs.run.checkpoint import CheckpointError

REPO = Path(__file__).resolve().parent.parent
N = 4
CHAIN_AGENT = {
    "alpha": 0.5,
    "gamma": 0.9,
    "number_splits": 7,
    "obs_low": [0.0],
    "obs_high": [7.0],
    "num_envs": 2,
    "chunk_steps": 10,
    "total_steps": 40,
}


@pytest.fixture(scope="module")
def balance(get_batched):
    """CartpoleBalance, batched over N envs: one jitted reset and step for the session."""
    return get_batched("CartpoleBalance-v0", N)


# ------------------------------------------------------------------------ actions
def test_wrong_action_shape_fails_at_trace_time_naming_the_shape(balance):
    benv, _, _ = balance
    env = benv.env
    s = jax.eval_shape(env.reset, jax.random.key(0))  # tracing only: nothing compiles
    traced = []

    def step(state, action):
        traced.append(action.shape)
        return env.step(state, action)

    with pytest.raises(ValueError, match=r"expected an action of shape \(1,\)"):
        jax.jit(step)(s, jnp.zeros((3,)))
    assert traced == [(3,)]  # raised while tracing, nothing ran on device
    with pytest.raises(TypeError, match="floating-point.*Box"):
        jax.jit(env.step)(s, jnp.zeros((1,), jnp.int32))
    bs = jax.eval_shape(benv.reset, jax.random.key(0))
    with pytest.raises(ValueError, match=r"expected actions of shape \(4, 1\)"):
        jax.jit(benv.step)(bs, jnp.zeros((N,)))


def test_out_of_range_actions_are_clipped(balance):
    benv, reset, step = balance
    s = reset(jax.random.key(1))
    over = step(s, jnp.array([[5.0], [-5.0], [1.5], [-1e30]]))
    edge = step(s, jnp.array([[1.0], [-1.0], [1.0], [-1.0]]))
    np.testing.assert_array_equal(np.asarray(over.data.qpos), np.asarray(edge.data.qpos))
    np.testing.assert_array_equal(np.asarray(over.info["nan_actions"]), np.zeros(N))


def test_nan_and_inf_actions_are_zeroed_counted_and_isolated(balance):
    """Each non-finite action acts as 0 and is counted for its own env only."""
    benv, reset, step = balance
    s = reset(jax.random.key(2))
    bad = step(s, jnp.array([[jnp.nan], [jnp.inf], [0.3], [-jnp.inf]]))
    good = step(s, jnp.array([[0.0], [0.0], [0.3], [0.0]]))
    assert np.asarray(bad.info["nan_actions"]).tolist() == [1, 1, 0, 1]
    assert np.asarray(good.info["nan_actions"]).tolist() == [0, 0, 0, 0]
    for a, b in zip(jax.tree.leaves(bad.data), jax.tree.leaves(good.data), strict=True):
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))
    np.testing.assert_array_equal(np.asarray(bad.obs), np.asarray(good.obs))


def test_extreme_actions_keep_the_state_finite(balance):
    """60 steps of +-1e9 / +-inf / NaN: finite obs, rewards and physics throughout."""
    benv, reset, step = balance
    s = reset(jax.random.key(3))
    values = jnp.array([1e9, -1e9, jnp.inf, jnp.nan], jnp.float32)
    for t in range(60):
        s = step(s, jnp.roll(values, t)[:, None])
        for x in (s.obs, s.reward, s.data.qpos, s.data.qvel, s.info["final_obs"]):
            assert np.all(np.isfinite(np.asarray(x))), t
    assert int(np.asarray(s.info["nan_actions"]).sum()) == 2  # NaN and inf, each step


def test_diverged_env_is_flagged_reset_and_the_others_untouched(balance):
    """A velocity past the documented bound (finite, not NaN) also terminates."""
    benv, reset, step = balance
    s = reset(jax.random.key(4))
    bound = benv.config.divergence_bound
    qvel = s.data.qvel.at[2, 0].set(10 * bound)
    poisoned = s.replace(data=s.data.replace(qvel=qvel))
    a = jnp.full((N, 1), 0.5, jnp.float32)
    clean, bad = step(s, a), step(poisoned, a)
    assert np.asarray(bad.info["diverged"]).tolist() == [False, False, True, False]
    assert bool(bad.terminated[2]) and int(bad.time[2]) == 0 and float(bad.reward[2]) == 0.0
    assert np.all(np.abs(np.asarray(bad.data.qvel[2])) < bound)  # reset to a fresh start
    assert np.all(np.abs(np.asarray(bad.info["final_obs"][2])) <= bound)
    for i in (0, 1, 3):
        for x, y in zip(jax.tree.leaves(clean), jax.tree.leaves(bad), strict=True):
            if jax.dtypes.issubdtype(x.dtype, jax.dtypes.prng_key):
                x, y = jax.random.key_data(x), jax.random.key_data(y)
            np.testing.assert_array_equal(np.asarray(x[i]), np.asarray(y[i]))


def test_batched_reset_and_step_compile_once(balance):
    """Feeding step's output back in, NaN actions and auto-resets never retrace."""
    benv, reset, step = balance
    s = reset(jax.random.key(5))
    s = reset(jax.random.key(6))
    for t in range(30):
        a = jnp.full((N, 1), jnp.nan if t % 3 == 0 else 1.0, jnp.float32)
        s = step(s, a)
    assert bool(np.asarray(s.info["final_length"]).max() > 0)
    assert reset._cache_size() == 1
    assert step._cache_size() == 1


# ------------------------------------------------------------------------ configs
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


# -------------------------------------------------------------------- command line
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


# --------------------------------------------------------------------- checkpoints
@pytest.fixture()
def saved(tmp_path):
    state = {"w": jnp.arange(6.0).reshape(2, 3), "key": jax.random.key(1), "n": jnp.int32(4)}
    path = tmp_path / "ck.npz"
    checkpoint.save(path, state, {"chunk": 1})
    return path, state


def test_checkpoint_write_is_atomic(saved, monkeypatch):
    """A crash (or Ctrl-C) during the rename keeps the old file and leaves no temp file."""
    path, state = saved
    before = path.read_bytes()

    def crash(src, dst):
        raise KeyboardInterrupt

    monkeypatch.setattr(files.os, "replace", crash)  # the rename every atomic write ends with
    newer = {**state, "w": state["w"] + 100.0}
    with pytest.raises(KeyboardInterrupt):
        checkpoint.save(path, newer, {"chunk": 2})
    assert path.read_bytes() == before
    assert sorted(p.name for p in path.parent.iterdir()) == [path.name]
    restored, meta = checkpoint.load(path, jax.eval_shape(lambda: state))
    assert meta == {"chunk": 1}
    np.testing.assert_array_equal(restored["w"], state["w"])


def test_checkpoint_is_versioned_and_other_versions_are_refused(saved, tmp_path):
    path, state = saved
    with np.load(path, allow_pickle=False) as npz:
        arrays = {k: npz[k] for k in npz.files}
    meta = json.loads(arrays["__meta__"].tobytes())
    assert meta["format"] == "jaxenvs-checkpoint" and meta["version"] == checkpoint.FORMAT_VERSION
    assert re.fullmatch(r"[0-9a-f]{64}", meta["sha256"])
    assert all(a.dtype != object for a in arrays.values())
    meta["version"] = checkpoint.FORMAT_VERSION + 1
    arrays["__meta__"] = np.frombuffer(json.dumps(meta).encode(), np.uint8)
    future = tmp_path / "future.npz"
    np.savez(future, **arrays)
    with pytest.raises(CheckpointError, match=rf"future\.npz.*version {meta['version']} is not"):
        checkpoint.load(future, jax.eval_shape(lambda: state))
    garbage = tmp_path / "garbage.npz"
    garbage.write_bytes(os.urandom(512))
    with pytest.raises(CheckpointError, match="garbage.npz.*truncated or corrupt"):
        checkpoint.load(garbage, jax.eval_shape(lambda: state))
    empty = tmp_path / "empty.npz"
    empty.write_bytes(b"")
    with pytest.raises(CheckpointError, match="empty.npz"):
        checkpoint.read(empty)


def test_no_pickle_anywhere_in_the_package():
    pattern = re.compile(
        r"^\s*(import|from)\s+(pickle|cPickle|cloudpickle|dill|joblib|shelve)\b"
        r"|allow_pickle\s*=\s*True|torch\.(save|load)\b",
        re.M,
    )
    offenders = [
        f"{p.relative_to(REPO)}: {m.group(0).strip()}"
        for p in sorted((REPO / "jaxenvs").rglob("*.py"))
        for m in pattern.finditer(p.read_text())
    ]
    assert not offenders, offenders
    assert "allow_pickle=False" in (REPO / "jaxenvs/run/checkpoint.py").read_text()


def test_batch_not_divisible_by_devices_is_one_line(tmp_path):
    """Two forced CPU devices, three envs: the key and the flag to change are named."""
    proc = subprocess.run(
        [sys.executable, "-m", "jaxenvs", "train", "CartPole-v0", "--algo", "qlearning"]
        + ["--num-envs", "3", "--devices", "2", "--out", str(tmp_path / "run")]
        + ["--no-compile-cache", "--quiet"],
        capture_output=True,
        text=True,
        timeout=300,
        env={**os.environ, "XLA_FLAGS": "--xla_force_host_platform_device_count=2"},
    )
    assert proc.returncode == 2, proc.stderr
    assert "Traceback" not in proc.stderr
    assert "num_envs=3 does not divide evenly over 2 devices" in proc.stderr
    assert "--devices" in proc.stderr
