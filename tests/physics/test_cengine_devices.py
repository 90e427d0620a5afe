"""The C engine over several CPU host devices: each device steps its own slice of the batch.

The CPU's device count is fixed when JAX starts, so the checks run in a subprocess with 2
forced host devices (on the native engine and on the callback path); it prints JSON and
writes arrays, compared here with the same batch on one device.
"""

from __future__ import annotations

import json
import re
import textwrap
from pathlib import Path

import numpy as np
import pytest
from host_devices import run_with_devices

_SCRIPT = textwrap.dedent(
    """
    import json, re, sys
    import jax, numpy as np
    import jaxenvs
    from jaxenvs.actions import random_actions

    out, runs = sys.argv[1], json.loads(sys.argv[2])
    res, arrays = {"devices": jax.local_device_count()}, {}
    for (task, num_envs, steps), n in [(r, n) for r in runs for n in (2, 1)]:
        benv = jaxenvs.make(task, num_envs=num_envs, physics="c", devices=n)

        def run(key, benv=benv):
            def body(s, k):
                s = benv.step(s, random_actions(benv.env, k, (benv.num_envs,)))
                return s, (s.obs, s.reward, s.done)
            return jax.lax.scan(body, benv.reset(key), jax.random.split(key, steps))

        fn = jax.jit(run)
        text = fn.lower(jax.random.key(3)).compile().as_text()
        state, traj = fn(jax.random.key(3))
        side = "spread" if n == 2 else "one"
        tag = f"{task}_{side}"
        res[f"{task}_devices_{side}"] = benv.devices
        res[f"{task}_threads_{side}"] = benv.env.sim.engine.threads
        res[f"{task}_shards_{side}"] = len(state.obs.sharding.device_set)
        # every engine call of the compiled program: its qpos-shaped result and threads
        res[f"{task}_calls_{side}"] = [
            line for line in text.splitlines()
            if re.search(r"custom-call.*(jaxenvs|xla_ffi_python_cpu_callback|callback)", line)
        ]
        for i, x in enumerate(jax.tree.leaves((state.data, traj))):
            arrays[f"{tag}_{i:03d}"] = np.asarray(x)
    np.savez(out + ".npz", **arrays)
    with open(out + ".json", "w") as f:
        json.dump(res, f)
    """
)


_RUNS = [("CartPole-v0", 8, 24), ("HexapodWalk-v0", 4, 4)]


def _run(tmp: Path, native: bool, runs: list) -> tuple[dict, dict]:
    """The ``runs`` (of :data:`_RUNS`) in one subprocess."""
    out = tmp / "res"
    env = {} if native else {"JAXENVS_NATIVE": "0"}
    run_with_devices(2, _SCRIPT, [str(out), json.dumps(runs)], env)
    return json.loads(Path(f"{out}.json").read_text()), dict(np.load(f"{out}.npz"))


@pytest.fixture(scope="module")
def native_run(tmp_path_factory):
    return _run(tmp_path_factory.mktemp("cdevices"), True, _RUNS[:1])


@pytest.fixture(scope="module")
def callback_run(tmp_path_factory):
    return _run(tmp_path_factory.mktemp("cdevices_callback"), False, _RUNS[:1])


@pytest.fixture(scope="module")
def walker_run(tmp_path_factory):
    return _run(tmp_path_factory.mktemp("cdevices_walker"), True, _RUNS[1:])


def _check_bit_identical(arrays: dict, task: str) -> None:
    one = sorted(k for k in arrays if k.startswith(f"{task}_one_"))
    assert one and len(one) == sum(k.startswith(f"{task}_spread_") for k in arrays)
    for key in one:
        a, b = arrays[key], arrays[key.replace("_one_", "_spread_")]
        assert a.shape == b.shape and a.dtype == b.dtype, key
        np.testing.assert_array_equal(b, a, err_msg=key)


@pytest.mark.full  # a 2-device subprocess: multi-device runs are the long tier's
def test_c_batch_over_two_devices_is_bit_identical_and_split(native_run):
    """8 CartPole envs under C spread over 2 host devices (``devices=2``): the same states as
    on one device, bit for bit, through auto-resets; each device's engine call sees 4 envs
    (not the whole batch) and half of the engine's threads."""
    _check_split(True, *native_run)


@pytest.mark.full  # a second 2-device subprocess
def test_callback_path_over_two_devices_is_bit_identical_unsplit(callback_run):
    """The Python-callback path (``JAXENVS_NATIVE=0``) on 2 devices: the same states as on
    one device; the step is a program per device, so its call too sees each device's 4
    envs (the callback is not partitioned, but a shard_map holds it as it is)."""
    _check_split(False, *callback_run)


def _check_split(native: bool, res: dict, arrays: dict) -> None:
    t = "CartPole-v0_"
    assert res["devices"] == 2
    assert (res[t + "devices_spread"], res[t + "shards_spread"]) == (2, 2)
    assert (res[t + "devices_one"], res[t + "shards_one"]) == (1, 1)
    leaves = sorted(k for k in arrays if k.startswith(t + "one_"))
    done = arrays[leaves[-1]]
    assert done.dtype == bool and done.any()  # episodes ended: the auto-reset ran
    _check_bit_identical(arrays, "CartPole-v0")
    # the compiled engine calls of the step: per device 4 envs on the spread layout, 8 on
    # one device, on both paths (the step is a program per device)
    nq = 2  # CartPole's qpos
    spread, one = res[t + "calls_spread"], res[t + "calls_one"]
    assert spread and one
    per_device = 4
    assert all(f"[{per_device},{nq}]" in c for c in spread), spread[0][:300]
    assert not any(f"[{12 - per_device},{nq}]" in c for c in spread), spread[0][:300]
    assert all(f"[8,{nq}]" in c for c in one), one[0][:300]
    if native:  # each device's call gets its share of the pool
        threads = res[t + "threads_spread"]
        share = max(1, threads // 2)
        assert all(re.search(rf"threads = {share} ", c) for c in spread), spread[0][-400:]
        assert all(re.search(rf"threads = {threads} ", c) for c in one), one[0][-400:]


@pytest.mark.full  # the walker's C programs, twice, in a third subprocess
def test_walker_c_over_two_devices_matches_one(walker_run):
    """The hexapod walker (contacts, several bodies) under C on 2 devices: bit-identical."""
    res, arrays = walker_run
    t = "HexapodWalk-v0_"
    assert (res[t + "devices_spread"], res[t + "shards_spread"]) == (2, 2)
    _check_bit_identical(arrays, "HexapodWalk-v0")
