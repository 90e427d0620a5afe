"""Several hosts on JAX's distributed runtime (:mod:`jaxenvs.run.distributed`): the flags
and variables that describe a cluster, and (full tier) one ``jaxenvs train`` run as two
processes of two CPU devices each on this host, against one process of four devices."""

from __future__ import annotations

import json
import os
import socket
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from jaxenvs.run import distributed
from jaxenvs.run.distributed import Cluster


def test_flags_and_variables_describe_a_cluster():
    assert distributed.cluster(None, None, None, {}) is None  # one process
    assert distributed.cluster(None, None, None, {"SLURM_NTASKS": "2", "SLURM_JOB_ID": "7"}) == {}
    env = {"JAX_COORDINATOR_ADDRESS": "h0:99", "JAX_NUM_PROCESSES": "4", "JAX_PROCESS_ID": "3"}
    assert distributed.cluster(None, None, None, env) == Cluster("h0:99", 4, 3)
    # a flag wins over its variable
    assert distributed.cluster("h1:5", None, 1, env) == Cluster("h1:5", 4, 1)
    assert distributed.cluster("h1:5", 2, 0, {}) == Cluster("h1:5", 2, 0)


@pytest.mark.parametrize(
    ("flags", "message"),
    [
        (("h:1", None, None), "JAX_NUM_PROCESSES, JAX_PROCESS_ID missing.*--num-processes"),
        (("h:1", 2, 2), "JAX_PROCESS_ID < JAX_NUM_PROCESSES, got 2 and 2"),
        (("h", 2, 0), "--coordinator must be host:port, got 'h'"),
        (("h:1", 0, 0), "JAX_NUM_PROCESSES >= 1"),
    ],
)
def test_an_incomplete_or_impossible_cluster_is_refused_by_name(flags, message):
    with pytest.raises(ValueError, match=message):
        distributed.cluster(*flags, {})


def test_a_single_process_writes_the_directory_it_was_given(tmp_path):
    assert not distributed.initialize(None)
    assert distributed.process_out_dir(tmp_path / "run") == tmp_path / "run"


_CONFIG = """\
algo: ppo
env: {id: CartPole-v0, physics: mjx}
agent: {total_steps: 2048, num_envs: 16, num_steps: 16, updates_per_chunk: 2,
        num_minibatches: 4, update_epochs: 2, actor_hidden: [16], critic_hidden: [16]}
train: {eval_episodes: 4, video: false}
"""
_CLI = "import sys; from jaxenvs.cli import main; sys.exit(main())"


def _train(out: Path, config: Path, devices: int, *cluster: str) -> subprocess.Popen[str]:
    env = {**os.environ, "JAX_PLATFORMS": "cpu"}
    env["XLA_FLAGS"] = f"--xla_force_host_platform_device_count={devices}"
    env.pop("JAX_NUM_CPU_DEVICES", None)
    args = ["train", "--config", str(config), "--devices", "4", "--out", str(out)]
    args += ["--no-compile-cache", "--quiet", *cluster]
    return subprocess.Popen(
        [sys.executable, "-c", _CLI, *args],
        env=env,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )


def _finish(proc: subprocess.Popen[str]) -> None:
    _, err = proc.communicate(timeout=900)
    assert proc.returncode == 0, err[-3000:]


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


@pytest.mark.full  # three training processes: the full tier
def test_two_processes_train_as_one_process_of_four_devices(tmp_path):
    """``jaxenvs train --coordinator --num-processes --process-id``: two processes of two
    CPU devices each train the run one process of four devices trains. Each writes its
    own directory (process 1's with ``.process1``) holding the whole gathered checkpoint,
    the same in both; against one process the parameters agree to the last bits the
    collectives' order may change, and the episodes and evaluation are the same."""
    config = tmp_path / "cfg.yaml"
    config.write_text(_CONFIG)
    address = f"127.0.0.1:{_free_port()}"
    procs = [
        _train(
            tmp_path / "two",
            config,
            2,
            "--coordinator",
            address,
            "--num-processes",
            "2",
            "--process-id",
            str(k),
        )  # fmt: skip
        for k in (0, 1)
    ]
    for proc in procs:
        _finish(proc)
    _finish(_train(tmp_path / "one", config, 4))
    ckpt = {d: np.load(tmp_path / d / "checkpoint.npz") for d in ("one", "two", "two.process1")}
    leaves = sorted(k for k in ckpt["one"] if k.startswith("leaf_"))
    assert leaves and all(k in ckpt["two"] for k in leaves)
    for k in leaves:
        np.testing.assert_array_equal(ckpt["two"][k], ckpt["two.process1"][k], err_msg=k)
        a, b = ckpt["one"][k], ckpt["two"][k]
        assert a.shape == b.shape and a.dtype == b.dtype, k
        if np.issubdtype(a.dtype, np.floating):
            np.testing.assert_allclose(a, b, rtol=1e-5, atol=1e-6, err_msg=k)
        else:
            np.testing.assert_array_equal(a, b, err_msg=k)
    summaries = [json.loads((tmp_path / d / "summary.json").read_text()) for d in ckpt]
    for key in ("episodes", "env_steps", "eval_mean_return"):
        assert len({s[key] for s in summaries}) == 1, (key, [s[key] for s in summaries])
