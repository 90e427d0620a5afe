"""Env batches and PPO spread over several devices (jaxenvs.core.sharding), on MJX.

The multi-device checks run in subprocesses, because the CPU device count
(``XLA_FLAGS=--xla_force_host_platform_device_count=N``) must be set before JAX starts.
Each writes its results to an ``.npz``; this module compares them. MJX, because its
programs are what the compiler partitions over the devices (the C engine's host callback
runs on one device whatever the mesh).

* Default tier: the mesh, placement and argument checks that need no second device.
* Full tier, a smoke test (``smoke``): one process with 2 devices, 4 envs of
  CartpoleStayUp-v0 (no scan unrolling: the cheapest MJX rollout to compile), a rollout on
  meshes of 1 and 2 devices; about 11 s on two cores.
* Full tier (``runs``): one process with 2 devices and one with 4, run side by side,
  between them covering meshes of 1, 2 and 4 devices for both the rollout and PPO on
  CartpoleBalance-v0. On two idle cores that takes about 1.5 min (each subprocess spends
  about 75 s of CPU time, mostly compiling).

Tolerances: the sharded rollout does the same per-env arithmetic as the one-device one,
so it must match to 1e-6 (it is bitwise equal on the CPU); PPO's gradient and statistics
means are sums over envs that the compiler splits into per-device partial sums, so float32
rounding may differ: parameters must match to 1e-4 after two updates.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import textwrap
from pathlib import Path
from typing import Any

import jax
import numpy as np
import pytest

from jaxenvs.core import sharding
from jaxenvs.core.placement import ENV_AXIS

ROLLOUT_TOL = 1e-6
PPO_TOL = 1e-4

_SCRIPT = textwrap.dedent(
    """
    import json, sys
    import jax, numpy as np
    import jaxenvs
    from jaxenvs.core import sharding as sh
    from jaxenvs.agents import ppo
    from jaxenvs.run.placement import shard_trainer_fns

    out_path = sys.argv[1]
    run = json.loads(sys.argv[2])
    rollout_meshes, ppo_meshes = run["rollout_meshes"], run["ppo_meshes"]
    assert jax.device_count() == max(rollout_meshes + ppo_meshes), jax.devices()
    env_id = run["env_id"]
    # auto-resets inside (episodes of 10 steps); MJX, stated, not picked by "auto"
    benv = jaxenvs.make(env_id, num_envs=run["num_envs"], episode_length=10, physics="mjx")
    cfg = ppo.PPOConfig(total_steps=256, num_envs=8, num_steps=8, updates_per_chunk=1,
                        update_epochs=1, num_minibatches=2, actor_hidden=(16,),
                        critic_hidden=(16,))
    trainer = ppo.make_trainer(jaxenvs.make(env_id, episode_length=10, physics="mjx"), cfg)
    arrays, checks = {}, {}
    for n in rollout_meshes:
        mesh = sh.make_mesh(n)
        state, rewards = sh.make_sharded_rollout(benv, mesh, run["steps"])(jax.random.key(3))
        arrays[f"rollout{n}_rewards"] = np.asarray(rewards)
        arrays[f"rollout{n}_obs"] = np.asarray(state.obs)
        arrays[f"rollout{n}_qpos"] = np.asarray(state.data.qpos)
        arrays[f"rollout{n}_time"] = np.asarray(state.time)
        leaves = jax.tree.leaves(state)
        checks[f"rollout{n}_split"] = all(sh.is_split(x, mesh) for x in leaves)
        checks[f"rollout{n}_rewards_split"] = sh.is_split(rewards, mesh, axis=1)
        checks[f"rollout{n}_devices"] = sh.num_shards((state, rewards))
    for n in ppo_meshes:
        mesh = sh.make_mesh(n)
        init, chunk = shard_trainer_fns(trainer, mesh, cfg.num_envs, num_seeds=1)
        rs = init(jax.random.split(jax.random.key(0), 1))
        for _ in range(2):
            rs, metrics = chunk(rs)
        for i, leaf in enumerate(jax.tree.leaves(rs.params)):
            arrays[f"ppo{n}_param{i}"] = np.asarray(leaf)
        arrays[f"ppo{n}_loss"] = np.asarray(metrics["loss"])
        arrays[f"ppo{n}_obs"] = np.asarray(rs.env_state.obs)
        checks[f"ppo{n}_env_split"] = all(
            sh.is_split(x, mesh, axis=1) for x in jax.tree.leaves(rs.env_state))
        checks[f"ppo{n}_params_replicated"] = all(
            sh.is_replicated(x, mesh) for x in jax.tree.leaves(rs.params))
    if jax.device_count() > 1:
        try:
            sh.make_sharded_rollout(
                jaxenvs.make(env_id, num_envs=7, physics="mjx"), sh.make_mesh(2), 2)
        except ValueError as err:
            checks["uneven_error"] = str(err)
    np.savez(out_path, **arrays)
    print("CHECKS " + json.dumps(checks))
    """
)


def _launch(
    tmp: Path,
    devices: int,
    rollout_meshes: list[int],
    ppo_meshes: list[int],
    env_id: str = "CartpoleBalance-v0",
    num_envs: int = 8,
    steps: int = 25,
) -> tuple[subprocess.Popen[str], Path]:
    out = tmp / f"devices{devices}.npz"
    env = dict(os.environ)
    env["XLA_FLAGS"] = (
        env.get("XLA_FLAGS", "") + f" --xla_force_host_platform_device_count={devices}"
    ).strip()
    env["JAX_PLATFORMS"] = "cpu"
    run = dict(
        rollout_meshes=rollout_meshes,
        ppo_meshes=ppo_meshes,
        env_id=env_id,
        num_envs=num_envs,
        steps=steps,
    )
    proc = subprocess.Popen(
        [sys.executable, "-c", _SCRIPT, str(out), json.dumps(run)],
        env=env,
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
    )
    return proc, out


def _collect(procs: list[tuple[subprocess.Popen[str], Path]]) -> dict[str, Any]:
    arrays: dict[str, np.ndarray] = {}
    checks: dict[str, Any] = {}
    for proc, out in procs:
        log, _ = proc.communicate(timeout=900)
        assert proc.returncode == 0, log[-4000:]
        line = [x for x in log.splitlines() if x.startswith("CHECKS ")][-1]
        checks.update(json.loads(line[len("CHECKS ") :]))
        with np.load(out) as data:
            arrays.update({k: data[k] for k in data.files})
    return {"arrays": arrays, "checks": checks}


@pytest.fixture(scope="module")
def runs(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Any]:
    """Both subprocesses, run in parallel: arrays and checks of meshes 1, 2 and 4 (each
    compile split so the two take about as long)."""
    tmp = tmp_path_factory.mktemp("sharding")
    return _collect([_launch(tmp, 2, [1, 2], [2]), _launch(tmp, 4, [4], [1, 4])])


@pytest.fixture(scope="module")
def smoke(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Any]:
    """One subprocess with 2 devices: a 4-env rollout of 12 steps on meshes of 1 and 2."""
    tmp = tmp_path_factory.mktemp("sharding_smoke")
    launched = _launch(tmp, 2, [1, 2], [], env_id="CartpoleStayUp-v0", num_envs=4, steps=12)
    return _collect([launched])


@pytest.mark.full  # a 2-device subprocess compiling MJX (~11 s on 2 cores): the full tier
def test_two_device_rollout_smoke(smoke: dict[str, Any]) -> None:
    """The sharded rollout on 2 devices equals the one-device one, crosses episode ends,
    stays split; an uneven batch is refused naming both numbers."""
    a, c = smoke["arrays"], smoke["checks"]
    for name in ("rewards", "obs", "qpos"):
        np.testing.assert_allclose(a[f"rollout2_{name}"], a[f"rollout1_{name}"], atol=ROLLOUT_TOL)
    np.testing.assert_array_equal(a["rollout2_time"], a["rollout1_time"])
    assert a["rollout1_time"].max() < 10 and np.abs(a["rollout1_rewards"]).sum() > 0
    for n in (1, 2):
        assert c[f"rollout{n}_split"] and c[f"rollout{n}_rewards_split"]
        assert c[f"rollout{n}_devices"] == n
    assert "num_envs=7" in c["uneven_error"] and "2 devices" in c["uneven_error"]


# ------------------------------------------------------------------- full tier: 1, 2, 4
@pytest.mark.full
@pytest.mark.parametrize("n", [2, 4])
def test_sharded_rollout_matches_one_device(runs: dict[str, Any], n: int) -> None:
    a = runs["arrays"]
    for name in ("rewards", "obs", "qpos"):
        np.testing.assert_allclose(
            a[f"rollout{n}_{name}"], a[f"rollout1_{name}"], atol=ROLLOUT_TOL, rtol=0
        )
    # the rollout crossed episode ends (length 10, 25 steps), so auto-reset was exercised
    assert a["rollout1_time"].max() < 10
    np.testing.assert_array_equal(a[f"rollout{n}_time"], a["rollout1_time"])
    assert np.abs(a["rollout1_rewards"]).sum() > 0


@pytest.mark.full
@pytest.mark.parametrize("n", [1, 2, 4])
def test_sharded_rollout_outputs_stay_sharded(runs: dict[str, Any], n: int) -> None:
    c = runs["checks"]
    assert c[f"rollout{n}_split"], f"a final-state leaf is not split over {n} devices"
    assert c[f"rollout{n}_rewards_split"]
    assert c[f"rollout{n}_devices"] == n


@pytest.mark.full
@pytest.mark.parametrize("n", [2, 4])
def test_sharded_ppo_matches_one_device(runs: dict[str, Any], n: int) -> None:
    a = runs["arrays"]
    params = sorted(k for k in a if k.startswith("ppo1_param"))
    assert params
    for k in params:
        np.testing.assert_allclose(a[k.replace("ppo1", f"ppo{n}")], a[k], atol=PPO_TOL, rtol=0)
    np.testing.assert_allclose(a[f"ppo{n}_loss"], a["ppo1_loss"], atol=PPO_TOL, rtol=1e-4)
    np.testing.assert_allclose(a[f"ppo{n}_obs"], a["ppo1_obs"], atol=PPO_TOL, rtol=0)


@pytest.mark.full
@pytest.mark.parametrize("n", [1, 2, 4])
def test_sharded_ppo_state_layout(runs: dict[str, Any], n: int) -> None:
    c = runs["checks"]
    assert c[f"ppo{n}_env_split"], "env states must stay split over the devices"
    assert c[f"ppo{n}_params_replicated"], "network params must be replicated"


@pytest.mark.full
def test_uneven_batch_error_names_both_numbers(runs: dict[str, Any]) -> None:
    msg = runs["checks"]["uneven_error"]
    assert "num_envs=7" in msg and "2 devices" in msg


# ----------------------------------------------------------------------- in-process units
def test_validate_batch() -> None:
    sharding.validate_batch(8, 4)
    sharding.validate_batch(5, 1)
    with pytest.raises(ValueError, match=r"num_envs=10 does not divide evenly over 4 devices"):
        sharding.validate_batch(10, 4)


def test_make_mesh_counts() -> None:
    mesh = sharding.make_mesh()
    assert mesh.size == jax.device_count() and mesh.axis_names == (ENV_AXIS,)
    assert sharding.make_mesh(1).size == 1
    with pytest.raises(ValueError, match="only"):
        sharding.make_mesh(jax.device_count() + 1)
    with pytest.raises(ValueError, match="positive"):
        sharding.make_mesh(0)


def test_shard_batch_places_leaves() -> None:
    mesh = sharding.make_mesh(1)
    tree = {"batch": np.arange(6.0).reshape(3, 2), "scalar": np.float32(1.0)}
    placed = sharding.shard_batch(tree, mesh)
    assert placed["batch"].sharding.spec == sharding.batch_sharding(mesh).spec
    assert placed["scalar"].sharding.is_fully_replicated
    np.testing.assert_array_equal(np.asarray(placed["batch"]), tree["batch"])


def test_under_fields_picks_paths() -> None:
    pred = sharding.under_fields("env_state")
    tree = {"env_state": {"obs": np.zeros((4, 2))}, "params": {"w": np.zeros((4, 2))}}
    mesh = sharding.make_mesh(1)
    sh = sharding.tree_shardings(tree, mesh, pred)
    assert sh["env_state"]["obs"].spec == sharding.batch_sharding(mesh).spec
    assert sh["params"]["w"].is_fully_replicated


def test_distributed_args_from_environment() -> None:
    assert sharding.distributed_args({}) is None
    full = {
        "JAX_COORDINATOR_ADDRESS": "host0:1234",
        "JAX_NUM_PROCESSES": "2",
        "JAX_PROCESS_ID": "1",
    }
    assert sharding.distributed_args(full) == {
        "coordinator_address": "host0:1234",
        "num_processes": 2,
        "process_id": 1,
    }
    with pytest.raises(ValueError, match="JAX_PROCESS_ID missing"):
        sharding.distributed_args({k: v for k, v in full.items() if k != "JAX_PROCESS_ID"})
    with pytest.raises(ValueError, match="0 <= JAX_PROCESS_ID"):
        sharding.distributed_args({**full, "JAX_PROCESS_ID": "2"})
    with pytest.raises(ValueError, match="integers"):
        sharding.distributed_args({**full, "JAX_NUM_PROCESSES": "two"})
    # launchers JAX detects on its own: initialise with no arguments
    assert sharding.distributed_args({"SLURM_JOB_ID": "7", "SLURM_NTASKS": "4"}) == {}
    assert sharding.distributed_args({"OMPI_COMM_WORLD_SIZE": "2"}) == {}
    assert sharding.distributed_args({"SLURM_JOB_ID": "7", "SLURM_NTASKS": "1"}) is None
    assert sharding.maybe_initialize_distributed({}) is False


def test_train_command_rejects_more_devices_than_present(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    from jaxenvs.cli import main

    too_many = jax.device_count() + 1
    argv = ["train", "CartPole-v0", "--algo", "qlearning", "--num-envs", "16"]
    code = main([*argv, "--devices", str(too_many), "--out", str(tmp_path / "run"), "--quiet"])
    assert code == 2
    err = capsys.readouterr().err
    assert f"asked for {too_many} devices" in err and "available" in err


@pytest.mark.full
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
