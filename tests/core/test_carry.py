"""A task's per-env carry survives auto-resets and is updated from each finished episode
(CountingCartPole, tests/counting_task.py: a count of finished episodes that also shifts
the next start)."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from counting_task import make
from host_devices import run_with_devices

from jaxenvs.core import BatchedEnv

STEPS = 23


def _rollout(benv: BatchedEnv, key: jax.Array, steps: int = STEPS):
    n = benv.num_envs

    def body(s, k):
        s = benv.step(s, jax.random.randint(k, (n,), 0, 2))
        return s, s.done

    start = benv.reset(key)
    return start, *jax.lax.scan(body, start, jax.random.split(key, steps))


@pytest.mark.parametrize("num_envs", [8, 128])  # the whole reset, and the compact one
def test_carry_counts_finished_episodes(num_envs):
    benv = BatchedEnv(make(), num_envs, devices=1)
    start, end, done = jax.jit(lambda k: _rollout(benv, k))(jax.random.key(0))
    assert np.all(np.asarray(start.carry) == 0)
    counts = np.asarray(done).sum(axis=0)
    assert counts.min() >= STEPS // 5  # every env finished (truncation at 5 steps)
    np.testing.assert_array_equal(np.asarray(end.carry), counts)


def test_a_fresh_start_reads_the_updated_carry():
    env = make()
    benv = BatchedEnv(env, 16, devices=1)

    @jax.jit
    def both(state, action):
        nxt = jax.vmap(env.step)(state, action)  # the step before the auto-reset
        after = benv.step(state, action)
        expected = jax.vmap(env.reset)(nxt.key).data.qpos[:, 0] + 1e-3 * after.carry
        return nxt, after, expected

    state, seen = benv.reset(jax.random.key(1)), 0
    for i in range(12):
        nxt, state, expected = both(state, jnp.full((16,), i % 2))
        done = np.asarray(nxt.done)
        seen += int(done.sum())
        got = np.asarray(state.data.qpos[:, 0])
        np.testing.assert_allclose(got[done], np.asarray(expected)[done], atol=1e-7)
        assert np.all(np.asarray(state.carry)[done] == np.asarray(nxt.carry)[done] + 1)
    assert seen > 0 and np.asarray(state.carry).max() >= 2


def test_carry_under_vmap_over_seeds():
    benv = BatchedEnv(make(), 8, devices=1, compact_reset=False)
    keys = jax.random.split(jax.random.key(2), 3)
    _, end, done = jax.jit(jax.vmap(lambda k: _rollout(benv, k)))(keys)
    np.testing.assert_array_equal(np.asarray(end.carry), np.asarray(done).sum(axis=1))


def test_restart_advances_the_carry_of_the_masked_envs_only():
    benv = BatchedEnv(make(), 6, devices=1)
    state = benv.reset(jax.random.key(3))
    mask = jnp.array([True, False, True, False, False, True])
    out = jax.jit(benv.restart)(state, mask, jax.random.split(jax.random.key(4), 6))
    np.testing.assert_array_equal(np.asarray(out.carry), np.asarray(mask, np.int32))
    np.testing.assert_array_equal(np.asarray(out.time), 0)


def test_a_reset_starts_a_new_carry():
    env = make()
    state = env.reset(jax.random.key(5))
    assert int(state.carry) == 0
    assert int(env.next_carry(state)) == 1
    again = env.reset_carried(jax.random.key(5), None, env.next_carry(state))
    assert int(again.carry) == 1  # the carried start: reset's, the cart 1 mm to the right
    np.testing.assert_allclose(again.data.qpos[0], state.data.qpos[0] + 1e-3, atol=1e-7)


@pytest.mark.full
def test_carry_under_mjx():
    benv = BatchedEnv(make(physics="mjx"), 8, devices=1)
    _, end, done = jax.jit(lambda k: _rollout(benv, k))(jax.random.key(0))
    np.testing.assert_array_equal(np.asarray(end.carry), np.asarray(done).sum(axis=0))


_DEVICES = """
import os, sys
sys.path.insert(0, sys.argv[1])
import jax, numpy as np
from counting_task import make
from jaxenvs.core import BatchedEnv
assert jax.local_device_count() == 4
for physics, n in (("c", 2048), ("mjx", 64)):
    benv = BatchedEnv(make(physics=physics), n, devices=4)
    one = BatchedEnv(make(physics=physics), n, devices=1)
    def roll(b, key):
        def body(s, k):
            s = b.step(s, jax.random.randint(k, (n,), 0, 2))
            return s, s.done
        return jax.lax.scan(body, b.reset(key), jax.random.split(key, 12))
    end, done = jax.jit(lambda k: roll(benv, k))(jax.random.key(0))
    end1, _ = jax.jit(lambda k: roll(one, k))(jax.random.key(0))
    assert np.array_equal(np.asarray(end.carry), np.asarray(done).sum(axis=0)), physics
    assert np.array_equal(np.asarray(end.carry), np.asarray(end1.carry)), physics
    assert np.array_equal(np.asarray(end.obs), np.asarray(end1.obs)), physics
print("ok")
"""


@pytest.mark.full
def test_carry_over_several_devices():
    import os

    here = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
    assert "ok" in run_with_devices(4, _DEVICES, [here]).stdout
