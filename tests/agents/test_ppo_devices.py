"""PPO over several devices (4 XLA CPU host devices, in a subprocess): a program per
device that is deterministic, that trains the same batch sanely on 2 and 4 devices,
whose compiled chunk meets across devices only once per gradient step and once per
rollout, and seeds over devices with no collective at all (each seed as on one device).

The script writes its figures as JSON and arrays as .npz, compared here."""

from __future__ import annotations

import json
import textwrap
from pathlib import Path

import numpy as np
import pytest
from host_devices import run_with_devices

_SCRIPT = textwrap.dedent(
    r"""
    import json, re, sys
    import jax, jax.numpy as jnp, numpy as np
    import jaxenvs
    from jaxenvs.agents import ppo
    from jaxenvs.core import sharding

    out = sys.argv[1]
    res, arrays = {"devices": jax.device_count()}, {}
    env = jaxenvs.make("CartpoleStayUp-v0", episode_length=20, physics="c")
    cfg = ppo.PPOConfig(total_steps=1024, num_envs=16, num_steps=8, updates_per_chunk=2,
                        num_minibatches=4, update_epochs=3, actor_hidden=(16,),
                        critic_hidden=(16,), critic_info=("command",), normalize_rewards=True)
    keys = jax.random.split(jax.random.key(0), 2)

    def collectives(text):
        # every cross-device op of a compiled program, by the while loops it sits in:
        # 1 = an update (a rollout), 2 = an env step or an epoch, 3 = a gradient step
        comps, entry, cur = {}, None, None
        for line in text.splitlines():
            if line and not line[0].isspace() and line.rstrip().endswith("{"):
                words = line.split()
                cur = words[1] if words[0] == "ENTRY" else words[0]
                entry = cur if words[0] == "ENTRY" else entry
                comps[cur] = []
            elif cur is not None:
                comps[cur].append(line)
        depth, todo = {entry: 0}, [entry]
        while todo:
            c = todo.pop()
            for line in comps[c]:
                called = re.findall(r"(body|condition|to_apply|calls)=(%[\w.\-]+)", line)
                for names in re.findall(r"branch_computations=\{([^}]*)\}", line):
                    called += [("branch", n.strip()) for n in names.split(",")]
                for kind, name in called:
                    d = depth[c] + (kind == "body")
                    if name in comps and depth.get(name, -1) < d:
                        depth[name] = d
                        todo.append(name)
        found = {}
        for c, lines in comps.items():
            for line in lines:
                if re.search(r"= .*\b(all-reduce|all-gather|all-to-all|collective-permute|"
                             r"reduce-scatter)(-start)?\(", line):
                    found[str(depth.get(c, -1))] = found.get(str(depth.get(c, -1)), 0) + 1
        return found

    def train(n, chunks=2):
        trainer = ppo.make_trainer(env, cfg, sharding.make_mesh(n))
        init, chunk = jax.jit(jax.vmap(trainer.init)), jax.jit(jax.vmap(trainer.chunk))
        s = init(keys)
        for _ in range(chunks):
            s, m = chunk(s)
        return trainer, chunk, s, jax.device_get(m)

    for n in (2, 4):
        trainer, chunk, s, m = train(n)
        res[f"m{n}"] = {k: np.asarray(v).tolist() for k, v in m.items()}
        res[f"n{n}"] = np.asarray(s.obs_stats.n).tolist()
        res[f"steps{n}"] = trainer.steps_per_chunk
        arrays[f"kernel{n}"] = np.asarray(s.params["params"]["actor"]["Dense_0"]["kernel"])
        arrays[f"obs_mean{n}"] = np.asarray(s.obs_stats.mean)
        res[f"collectives{n}"] = collectives(chunk.lower(s).compile().as_text())
        obs = s.env_state.obs
        res[f"obs_split{n}"] = obs.sharding.shard_shape(obs.shape)[1] == 16 // n
        kernel = s.params["params"]["actor"]["Dense_0"]["kernel"]
        shards = [np.asarray(x.data) for x in kernel.addressable_shards]
        res[f"params_same{n}"] = len(shards) == n and all(
            np.array_equal(shards[0], x) for x in shards
        )
    # the same device count again: the same bits
    _, _, s, m = train(4)
    arrays["kernel4_again"] = np.asarray(s.params["params"]["actor"]["Dense_0"]["kernel"])
    res["m4_again"] = {k: np.asarray(v).tolist() for k, v in m.items()}

    # seeds over devices: 4 seeds, one a device, as the runner lays them out
    from jaxenvs.run.placement import seeds_programs
    trainer = ppo.make_trainer(env, cfg)
    keys4 = jax.random.split(jax.random.key(1), 4)
    init, chunk = seeds_programs(trainer, sharding.make_mesh(4))
    s = init(keys4)
    s, m = chunk(s)
    res["seeds_collectives"] = collectives(chunk.lower(s).compile().as_text())
    res["seeds_split"] = s.env_state.obs.sharding.shard_shape(s.env_state.obs.shape)[0] == 1
    arrays["seeds_kernel"] = np.asarray(s.params["params"]["actor"]["Dense_0"]["kernel"])
    one = jax.jit(jax.vmap(trainer.chunk))(jax.jit(jax.vmap(trainer.init))(keys4[2:3]))[0]
    arrays["seed2_alone"] = np.asarray(one.params["params"]["actor"]["Dense_0"]["kernel"])[0]
    json.dump(res, open(out + ".json", "w"))
    np.savez(out + ".npz", **arrays)
    """
)


@pytest.fixture(scope="module")
def four_devices(tmp_path_factory):
    out = tmp_path_factory.mktemp("ppo_devices") / "res"
    run_with_devices(4, _SCRIPT, [str(out)])
    return json.loads(Path(f"{out}.json").read_text()), dict(np.load(f"{out}.npz"))


@pytest.mark.full  # a 4-device subprocess: the full tier
def test_a_program_per_device_is_deterministic(four_devices):
    res, arrays = four_devices
    assert res["devices"] == 4
    np.testing.assert_array_equal(arrays["kernel4"], arrays["kernel4_again"])
    assert res["m4"] == res["m4_again"]


@pytest.mark.full
def test_the_same_batch_on_two_and_four_devices_trains_sanely(four_devices):
    """The same 16 envs split 2 and 4 ways: the same env steps and normaliser counts
    (every device's observations merged: 16 at the start and 16 an env step), the env
    batch split and the parameters the same on every device, finite losses, and as many
    finished episodes give or take the keys' luck."""
    res, arrays = four_devices
    for n in (2, 4):
        m = res[f"m{n}"]
        assert res[f"steps{n}"] == 16 * 8 * 2
        assert m["env_steps"] == [2 * 16 * 8 * 2] * 2  # two chunks, two seeds
        np.testing.assert_allclose(res[f"n{n}"], 1e-4 + 16 + 2 * 2 * 8 * 16, rtol=1e-6)
        assert res[f"obs_split{n}"] and res[f"params_same{n}"]
        for key in ("loss", "value_loss", "entropy", "approx_kl", "mean_return"):
            assert np.all(np.isfinite(m[key])), (n, key)
        assert np.all(np.isfinite(arrays[f"obs_mean{n}"]))
    ep2, ep4 = np.asarray(res["m2"]["episodes"]), np.asarray(res["m4"]["episodes"])
    assert np.all(ep2 > 0) and np.all(np.abs(ep4 - ep2) <= 0.3 * ep2), (ep2, ep4)


@pytest.mark.full
def test_devices_meet_once_per_gradient_step_and_per_rollout(four_devices):
    """The compiled chunk's cross-device ops by loop depth: one all-reduce in the
    gradient step (depth 3: updates, epochs, minibatches), at most three per rollout
    (depth 1: the statistics' and episode sums, one per dtype, and the best return), none
    in an env step or an epoch (depth 2) nor outside the updates."""
    res, _ = four_devices
    for n in (2, 4):
        found = res[f"collectives{n}"]
        assert found.get("3") == 1, found
        assert 1 <= found.get("1", 0) <= 3, found
        assert set(found) <= {"1", "3"}, found


@pytest.mark.full
def test_seeds_over_devices_cross_no_device(four_devices):
    """Four seeds, one a device: no collective at all, the seed axis split, and a seed
    trained as it trains alone on one device (to rounding: another program)."""
    res, arrays = four_devices
    assert res["seeds_collectives"] == {}
    assert res["seeds_split"]
    np.testing.assert_allclose(arrays["seeds_kernel"][2], arrays["seed2_alone"], atol=1e-6)
