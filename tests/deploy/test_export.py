"""``jaxenvs export``: the ONNX and npz policies of a PPO run act as ``jaxenvs eval`` does on
observations of real rollouts, run without JAX, and bad input is one line."""

from __future__ import annotations

import dataclasses
import json
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import onnx
import pytest
import yaml

import jaxenvs
from jaxenvs import cli
from jaxenvs.deploy import export, parity, runtime
from jaxenvs.deploy.runtime import NumpyPolicy, PolicyFileError
from jaxenvs.run import runner

NUM_OBS = 10_240
#: two chunks of a tiny PPO run on the C engine: it need not learn, only move its weights
TINY_AGENT = {
    "total_steps": 512,
    "num_envs": 8,
    "num_steps": 32,
    "updates_per_chunk": 1,
    "update_epochs": 1,
    "num_minibatches": 1,
}
RUNS = {
    # discrete actions, a normaliser, two seeds (export picks eval's best): the default tier
    "CartPole-v0": ({"normalize_obs": True}, {"num_seeds": 2}),
    # continuous actions: the full tier (a second PPO compile)
    "Reacher-v0": ({"normalize_obs": True}, {"num_seeds": 1}),
}
IDS = ["CartPole-v0", pytest.param("Reacher-v0", marks=pytest.mark.full)]


def _train(env_id: str, out: Path) -> Path:
    agent, train = RUNS[env_id]
    config = out.parent / f"{env_id}.yaml"
    config.write_text(
        yaml.safe_dump(
            {
                "algo": "ppo",
                "env": {"id": env_id, "physics": "c"},
                "agent": {**TINY_AGENT, **agent},
                "train": {**train, "eval_episodes": 2, "video": False},
            }
        )
    )
    runner.train(runner.resolve_config(None, None, config), out, quiet=True)
    return out


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    """Per env id, on first use: the run directory of a tiny PPO run."""
    made: dict[str, Path] = {}

    def run(env_id: str) -> Path:
        if env_id not in made:
            made[env_id] = _train(env_id, tmp_path_factory.mktemp("runs") / env_id)
        return made[env_id]

    return run


@pytest.fixture(scope="module")
def exported(runs, tmp_path_factory):
    """Per env id, on first use: both exported files, the JAX policy, rollout observations
    and the JAX policy's actions on them."""
    made: dict[str, tuple] = {}

    def exports(env_id: str) -> tuple:
        if env_id not in made:
            out, run, paths = tmp_path_factory.mktemp("exported"), runs(env_id), {}
            for fmt in export.FORMATS:
                paths[fmt] = out / f"{env_id}.{fmt}"
                argv = ["export", str(run), "--format", fmt, "--out", str(paths[fmt])]
                assert cli.main(argv) == 0
            seed = int(NumpyPolicy.load(paths["npz"]).metadata["seed"])
            policy = parity.jax_policy(run, seed)
            obs = parity.rollout_observations(policy, NUM_OBS)
            made[env_id] = (paths, policy, obs, policy.actions(obs))
        return made[env_id]

    return exports


@pytest.mark.parametrize("env_id", IDS)
def test_exported_policies_act_as_the_jax_policy(exported, env_id):
    paths, policy, obs, reference = exported(env_id)
    assert obs.shape == (NUM_OBS, policy.env.observation_size)
    assert np.unique(obs, axis=0).shape[0] > NUM_OBS // 2  # a real rollout, not one state
    onnx_act = parity.onnx_actions(paths["onnx"], obs)
    npz_act = NumpyPolicy.load(paths["npz"])(obs)
    for actions in (onnx_act, npz_act):
        row = parity.compare(reference, actions, policy.env.discrete)
        assert row["mismatches"] == 0 and row["max_abs_diff"] <= 1e-5, row
    if policy.env.discrete:
        assert onnx_act.dtype == npz_act.dtype == np.int64 and onnx_act.shape == (NUM_OBS,)
        assert len(np.unique(reference)) == policy.env.action_size  # both choices are met
    else:
        shape = (NUM_OBS, policy.env.action_size)
        assert onnx_act.dtype == npz_act.dtype == np.float32 and onnx_act.shape == shape
        assert np.abs(onnx_act).max() <= 1.0


def test_the_normaliser_and_the_seed_choice_are_inside(exported, runs, tmp_path):
    """Parity is not trivial: without the normaliser the actions differ; the export holds
    the seed ``eval`` found best, whose actions differ from the other seed's."""
    paths, policy, obs, reference = exported("CartPole-v0")
    full = NumpyPolicy.load(paths["npz"])
    assert full.normalizer is not None
    bare = dataclasses.replace(full, normalizer=None)
    assert np.count_nonzero(bare(obs) != reference) > NUM_OBS // 100
    # a policy without a normaliser (the shipped CartPole config's): its ONNX graph too
    onnx_path = tmp_path / "bare.onnx"
    onnx.save(export.onnx_model(bare), str(onnx_path))
    np.testing.assert_array_equal(parity.onnx_actions(onnx_path, obs), bare(obs))
    summary = json.loads((runs("CartPole-v0") / runner.SUMMARY_FILE).read_text())
    best = int(np.argmax(summary["eval_mean_return_per_seed"]))
    assert full.metadata["seed"] == str(best)
    other = parity.jax_policy(runs("CartPole-v0"), 1 - best)
    assert np.any(other.actions(obs) != reference)


@pytest.mark.parametrize("env_id", IDS)
def test_metadata_of_both_formats(exported, env_id):
    paths, policy, _, _ = exported(env_id)
    env = policy.env
    model = onnx.load(str(paths["onnx"]))
    onnx.checker.check_model(model)
    props = {p.key: p.value for p in model.metadata_props}
    assert props == NumpyPolicy.load(paths["npz"]).metadata
    assert props["env_id"] == env_id and props["jaxenvs_version"] == jaxenvs.__version__
    assert int(props["observation_size"]) == env.observation_size
    assert int(props["action_size"]) == env.action_size
    assert float(props["control_dt"]) == env.control_dt
    space = json.loads(props["action_space"])
    if env.discrete:
        assert space == {"type": "Discrete", "n": env.action_size}
    else:
        assert space["low"] == [-1.0] * env.action_size and space["shape"] == [env.action_size]
    assert json.loads(props["observation_space"])["low"][0] == "-inf"
    (inp,) = model.graph.input
    assert inp.name == "obs" and inp.type.tensor_type.shape.dim[0].dim_param  # batch: dynamic
    assert [o.name for o in model.graph.output] == ["action"]


#: run in a fresh process where ``import jax`` fails: ``python -c NO_JAX DIR`` checks the
#: exported files listed in DIR/cases.json against the JAX actions saved beside them
NO_JAX = """
import json, sys
sys.modules["jax"] = None
sys.path.insert(0, sys.argv[1])
import numpy as np, onnxruntime, runtime
try:
    import jax
    sys.exit("jax imported")
except ImportError:
    pass
for onnx_path, npz_path, obs_path, ref_path in json.load(open(sys.argv[1] + "/cases.json")):
    obs, ref = np.load(obs_path), np.load(ref_path)
    session = onnxruntime.InferenceSession(onnx_path, providers=["CPUExecutionProvider"])
    onnx_act = session.run(["action"], {"obs": obs})[0]
    npz_act = runtime.NumpyPolicy.load(npz_path)(obs)
    for act in (onnx_act, npz_act):
        assert act.shape == ref.shape and np.abs(act.astype(np.float64) - ref).max() <= 1e-5
assert not [m for m, v in sys.modules.items() if v and m.split(".")[0] in ("jax", "jaxenvs")]
print("ok")
"""


@pytest.mark.parametrize("env_id", IDS)
def test_exported_files_run_without_jax(exported, tmp_path, env_id):
    """The ONNX file in onnxruntime and the npz in a copy of runtime.py, in a process where
    ``import jax`` fails: the same actions as JAX's."""
    shutil.copy(runtime.__file__, tmp_path / "runtime.py")
    cases = []
    for paths, _, obs, reference in [exported(env_id)]:
        np.save(tmp_path / f"{env_id}_obs.npy", obs)
        np.save(tmp_path / f"{env_id}_ref.npy", reference)
        npys = [str(tmp_path / f"{env_id}_{k}.npy") for k in ("obs", "ref")]
        cases.append([str(paths["onnx"]), str(paths["npz"]), *npys])
    (tmp_path / "cases.json").write_text(json.dumps(cases))
    argv = [sys.executable, "-c", NO_JAX, str(tmp_path)]
    done = subprocess.run(argv, capture_output=True, text=True, cwd=tmp_path)
    assert done.returncode == 0 and done.stdout.strip() == "ok", done.stderr[-2000:]


def test_numpy_runtime_single_observation_and_bad_input(exported, runs, tmp_path):
    paths, _, obs, reference = exported("CartPole-v0")
    policy = NumpyPolicy.load(paths["npz"])
    assert policy(obs[0]) == reference[0] and policy(obs[0]).shape == ()
    with pytest.raises(ValueError, match=r"expected observations of shape \(4,\)"):
        policy(obs[:, :3])
    bad = tmp_path / "bad.npz"
    bad.write_bytes(paths["npz"].read_bytes()[:200])
    with pytest.raises(PolicyFileError, match="not a readable npz"):
        NumpyPolicy.load(bad)
    with pytest.raises(PolicyFileError, match="not an exported jaxenvs policy"):
        NumpyPolicy.load(runs("CartPole-v0") / runner.CHECKPOINT_FILE)
    with pytest.raises(PolicyFileError, match="no policy file"):
        NumpyPolicy.load(tmp_path / "missing.npz")


def _one_line_error(capsys, argv: list[str], match: str) -> None:
    capsys.readouterr()
    assert cli.main(argv) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and err.startswith("jaxenvs export: error:"), err
    assert match in err, err


@pytest.mark.full
def test_bad_input_is_one_line(runs, tmp_path, capsys):
    run = runs("Reacher-v0")
    tabular = tmp_path / "tabular"
    tabular.mkdir()
    resolved = runner.resolve_config("CartPole-v0", "qlearning")
    (tabular / runner.CONFIG_FILE).write_text(yaml.safe_dump(resolved.to_dict()))
    _one_line_error(capsys, ["export", str(tabular), "--format", "onnx"], "a qlearning run")
    no_ckpt = tmp_path / "no_checkpoint"
    no_ckpt.mkdir()
    shutil.copy(run / runner.CONFIG_FILE, no_ckpt)
    _one_line_error(capsys, ["export", str(no_ckpt), "--format", "npz"], "no checkpoint at")
    damaged = tmp_path / "damaged"
    shutil.copytree(run, damaged)
    ckpt = damaged / runner.CHECKPOINT_FILE
    ckpt.write_bytes(ckpt.read_bytes()[:-100])
    out = tmp_path / "kept.onnx"
    out.write_bytes(b"an earlier export")
    argv = ["export", str(damaged), "--format", "onnx", "--out", str(out)]
    _one_line_error(capsys, argv, "checkpoint")
    assert out.read_bytes() == b"an earlier export"  # a failed export leaves the file as it was
    _one_line_error(capsys, ["export", str(run), "--format", "tflite"], "unknown format 'tflite'")
    missing = tmp_path / "no_such_dir" / "p.onnx"
    _one_line_error(
        capsys, ["export", str(run), "--format", "onnx", "--out", str(missing)], "does not exist"
    )
    _one_line_error(
        capsys, ["export", str(run), "--format", "npz", "--out", str(tmp_path)], "is a directory"
    )
    _one_line_error(capsys, ["export", str(run), "--format", "npz", "--seed", "1"], "--seed")
    assert not [p.name for p in tmp_path.iterdir() if p.name.startswith(".")]  # no temp files
