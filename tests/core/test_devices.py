"""Batches spread over all local devices by default (BatchedEnv, the Gymnasium vector env),
and the one knob for how much of the machine to use (``jaxenvs.machine``).

The CPU's device count is fixed when JAX starts, so the multi-device checks run in a
subprocess with 4 forced host devices; it writes its results as JSON and arrays as .npz,
compared here. Rollouts must be bit-identical to one device (each env's arithmetic is the
same; only where it runs changes).
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest
from host_devices import run_with_devices

from jaxenvs import machine
from jaxenvs.core import placement

_SCRIPT = textwrap.dedent(
    """
    import json, sys, warnings
    import jax, jax.numpy as jnp, numpy as np
    import jaxenvs
    from jaxenvs.actions import random_actions
    from jaxenvs.core import placement

    out = sys.argv[1]
    res, arrays = {"devices": jax.local_device_count()}, {}

    def rollout(benv, steps=40):
        def run(key):
            def body(s, k):
                s = benv.step(s, random_actions(benv.env, k, (benv.num_envs,)))
                return s, (s.obs, s.reward, s.done)
            return jax.lax.scan(body, benv.reset(key), jax.random.split(key, steps))
        state, traj = jax.jit(run)(jax.random.key(7))
        return state, [np.asarray(x) for x in traj]

    for n in (None, 2, 1):
        benv = jaxenvs.make("CartPole-v0", num_envs=8, devices=n, physics="mjx")
        state, traj = rollout(benv)
        res[f"devices_{n}"] = benv.devices
        res[f"obs_shards_{n}"] = len(state.obs.sharding.device_set)
        for name, x in zip(("obs", "reward", "done"), traj):
            arrays[f"{name}_{n}"] = x
    # domain randomisation spread too
    benv = jaxenvs.make("Reacher-v0", num_envs=8, randomize=True, physics="mjx")
    res["randomized_devices"] = benv.devices
    arrays["dr_4"] = rollout(benv, 10)[1][0]
    arrays["dr_1"] = rollout(jaxenvs.make("Reacher-v0", num_envs=8, randomize=True,
                                           physics="mjx", devices=1), 10)[1][0]
    # uneven batches: the default spreads over a divisor; an explicit count must divide
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        res["uneven_devices"] = jaxenvs.make("CartPole-v0", num_envs=6, physics="mjx").devices
    res["uneven_warning"] = " ".join(str(w.message) for w in caught)
    try:
        jaxenvs.make("CartPole-v0", num_envs=6, devices=4)
    except ValueError as err:
        res["uneven_error"] = str(err)
    # the C engine's batches spread by default only from C_ENVS_PER_DEVICE envs a device
    res["c_devices"] = jaxenvs.make("CartPole-v0", num_envs=8, physics="c").devices
    res["c_devices_big"] = jaxenvs.make("CartPole-v0", num_envs=2048, physics="c").devices
    res["c_devices_mid"] = jaxenvs.make("CartPole-v0", num_envs=1024, physics="c").devices
    # a batch over 4 devices steps as a program per device on every engine, each device
    # resetting its own finished envs (compact: 64 envs each, 8 places; or whole); the
    # same states either way and as on one device, and no cross-device reduction a step
    import dataclasses
    from jaxenvs.core import BatchedEnv
    for physics in ("c", "mjx"):
        made = jaxenvs.make("CartPole-v0", num_envs=256, physics=physics, devices=4)
        for mode in ("compact", "whole"):
            tag = f"{physics}_{mode}"
            benv = BatchedEnv(made.env, 256, plan=dataclasses.replace(made.plan, reset=mode))
            res[f"reset_devices_{tag}"] = benv.devices
            state, traj = rollout(benv, 60)
            res[f"reset_shards_{tag}"] = len(state.obs.sharding.device_set)
            a = random_actions(benv.env, jax.random.key(1), (benv.num_envs,))
            hlo = jax.jit(benv.step).lower(state, a).compile().as_text()
            res[f"reset_all_reduce_{tag}"] = "all-reduce" in hlo
            for name, x in zip(("obs", "reward", "done"), traj):
                arrays[f"reset_{tag}_{name}"] = x
        one = BatchedEnv(made.env, 256, devices=1)
        for name, x in zip(("obs", "reward", "done"), rollout(one, 60)[1]):
            arrays[f"reset_{physics}_one_{name}"] = x
    # ... and a task with c_envs_per_device=None (the hexapod's) stays on one device
    res["c_walker_big"] = jaxenvs.make("HexapodWalk-v0", num_envs=2048, physics="c").devices
    # a program per device over a param given as a Python float (made an array, as jit does)
    from jax.sharding import Mesh
    from jaxenvs.core.placement import ENV_AXIS
    y, e = placement.per_device(
        Mesh(np.array(jax.devices()), (ENV_AXIS,)),
        lambda s, a, p: (s * p["k"] + a, jnp.zeros((s.shape[0], 0))),
        jnp.arange(8.0), jnp.ones(8), {"k": 2.0})
    res["per_device_float"] = [np.asarray(y).tolist(), list(e.shape), len(y.sharding.device_set)]
    arrays["c_2"] = rollout(jaxenvs.make("CartPole-v0", num_envs=8, physics="c", devices=2))[1][0]
    arrays["c_1"] = rollout(jaxenvs.make("CartPole-v0", num_envs=8, physics="c", devices=1))[1][0]
    # the Gymnasium vector env is spread as well, with the same numbers
    import gymnasium as gym
    obs = []
    for n in (None, 1):
        envs = gym.make_vec("jaxenvs/CartPole-v0", num_envs=8, physics="mjx",
                            vectorization_mode="vector_entry_point", devices=n)
        o, _ = envs.reset(seed=3)
        for _ in range(20):
            o, r, te, tr, info = envs.step(np.ones(8, np.int64))
        obs.append(o)
        envs.close()
    res["vector_equal"] = bool(np.array_equal(obs[0], obs[1]))
    np.savez(out + ".npz", **arrays)
    with open(out + ".json", "w") as f:
        json.dump(res, f)
    """
)


@pytest.fixture(scope="module")
def four_devices(tmp_path_factory):
    out = tmp_path_factory.mktemp("devices") / "res"
    run_with_devices(4, _SCRIPT, [str(out)])
    return json.loads(Path(f"{out}.json").read_text()), dict(np.load(f"{out}.npz"))


@pytest.mark.full  # a 4-device subprocess: the full tier
def test_batch_spreads_over_all_devices_by_default(four_devices):
    res, _ = four_devices
    assert res["devices"] == 4
    assert (res["devices_None"], res["devices_2"], res["devices_1"]) == (4, 2, 1)
    assert (res["obs_shards_None"], res["obs_shards_2"], res["obs_shards_1"]) == (4, 2, 1)
    assert res["randomized_devices"] == 4
    assert (res["c_devices"], res["c_devices_mid"], res["c_devices_big"]) == (1, 2, 4)
    assert res["c_walker_big"] == 1


@pytest.mark.full  # the 4-device subprocess above
def test_a_step_per_device_on_every_engine_resets_as_on_one_device(four_devices):
    """A batch over devices steps as a program per device on every engine: no
    cross-device reduction, the compact and the whole reset give the same states, and
    those of the same batch on one device."""
    res, arrays = four_devices
    tags = [f"{p}_{m}" for p in ("c", "mjx") for m in ("compact", "whole")]
    assert [res[f"reset_devices_{t}"] for t in tags] == [4] * 4
    assert [res[f"reset_shards_{t}"] for t in tags] == [4] * 4
    assert not any(res[f"reset_all_reduce_{t}"] for t in tags)
    assert res["per_device_float"] == [[2.0 * k + 1 for k in range(8)], [8, 0], 4]
    for physics in ("c", "mjx"):
        assert arrays[f"reset_{physics}_compact_done"].sum() > 60  # resets happened
        for tag in ("whole", "one"):
            for name in ("obs", "reward", "done"):
                got, want = (
                    arrays[f"reset_{physics}_compact_{name}"],
                    arrays[f"reset_{physics}_{tag}_{name}"],
                )
                if physics == "mjx" and tag == "one":
                    # MJX compiled for a device's 64 envs rounds a few last bits unlike the
                    # same program for 256 (docs/devices.md); C steps each env alike
                    np.testing.assert_allclose(got, want, rtol=0, atol=1e-4)
                else:
                    np.testing.assert_array_equal(got, want)


@pytest.mark.full  # a 4-device subprocess: the full tier
def test_spread_rollouts_agree_with_one_device(four_devices):
    """MJX over 4 and 2 devices (a program per device) against one: the same episodes, the
    numbers to the last few bits (MJX compiled per device's slice rounds some last bits
    unlike the whole batch's program; docs/devices.md); the C engine bit for bit."""
    _, arrays = four_devices
    assert arrays["done_1"].any()  # episodes ended: the auto-reset ran on every layout
    for name in ("obs", "reward", "done"):
        for n in ("None", "2"):
            np.testing.assert_allclose(arrays[f"{name}_{n}"], arrays[f"{name}_1"], atol=1e-4)
    np.testing.assert_array_equal(arrays["done_None"], arrays["done_1"])
    np.testing.assert_allclose(arrays["dr_4"], arrays["dr_1"], atol=1e-4)
    np.testing.assert_array_equal(arrays["c_2"], arrays["c_1"])


@pytest.mark.full  # a 4-device subprocess: the full tier
def test_uneven_batches(four_devices):
    res, _ = four_devices
    assert res["uneven_devices"] == 3
    assert "num_envs=6" in res["uneven_warning"] and "4 local devices" in res["uneven_warning"]
    assert "num_envs=6" in res["uneven_error"] and "4 or 8" in res["uneven_error"]


@pytest.mark.full  # a 4-device subprocess: the full tier
def test_vector_env_spread_matches_one_device(four_devices):
    res, _ = four_devices
    assert res["vector_equal"] is True


def test_divisible_devices():
    assert placement.divisible_devices(4096, 16) == 16
    assert placement.divisible_devices(1001, 16) == 13
    assert placement.divisible_devices(7, 16) == 7
    assert placement.divisible_devices(1, 8) == 1


_KNOB = textwrap.dedent(
    """
    import sys, warnings
    from jaxenvs import machine
    import jax
    if sys.argv[1] == "early":
        machine.use_cores(8)
        print(jax.local_device_count(), machine.cpu_threads())
    else:
        jax.devices()
        try:
            machine.use_cores(8)
        except RuntimeError as err:
            print("raised:", err)
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            machine.use_cores(8, strict=False)
        print("warned:", caught[0].message, machine.cpu_threads())
    """
)


def _knob(mode: str) -> str:
    env = {k: v for k, v in os.environ.items() if k not in ("XLA_FLAGS", "JAX_NUM_CPU_DEVICES")}
    proc = subprocess.run(
        [sys.executable, "-c", _KNOB, mode], env=env, capture_output=True, text=True, timeout=120
    )
    assert proc.returncode == 0, proc.stderr[-2000:]
    return proc.stdout


@pytest.mark.full
def test_use_cores_sets_devices_and_threads_before_jax_starts():
    assert _knob("early").split() == ["4", "8"]  # one XLA CPU device per two cores


@pytest.mark.full
def test_use_cores_too_late_says_how_to_fix():
    out = _knob("late")
    assert "raised: jaxenvs.machine.use_cores came after JAX started" in out
    assert "xla_force_host_platform_device_count=4" in out
    assert "warned:" in out and out.strip().endswith("8")  # the threads still change


def test_usable_cores_and_device_rule():
    assert machine.usable_cores() == len(os.sched_getaffinity(0))
    assert [placement.host_devices_for(n) for n in (1, 2, 3, 16)] == [1, 1, 1, 8]
