"""PPO's pieces alone, on hand-computed inputs: the whole minibatch loss (clipped
surrogate, value loss plain and clipped, entropy bonus, advantage normalisation, approx
KL), the minibatch shuffle, and the episode and chunk figures of a rollout."""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxenvs.agents import losses, ppo

# four samples, one in each corner of the clip: ratios 1.5 / 0.5 against advantages +-1
RATIOS = jnp.array([1.5, 0.5, 1.5, 0.5])
LOG_PROB = jnp.log(RATIOS)
OLD_LOG_PROB = jnp.zeros(4)
ADV = jnp.array([1.0, 1.0, -1.0, -1.0])
# value updates (clip 0.2): inside the clip; past it, the plain error larger; past it, the
# clipped error larger; below it, the plain error larger
VALUES = jnp.array([1.1, 3.0, 3.0, 0.0])
OLD_VALUES = jnp.array([1.0, 2.0, 1.0, 1.0])
RETURNS = jnp.array([2.0, 2.5, 3.0, 2.0])
PLAIN_V_LOSS = 0.5 * (0.81 + 0.25 + 0.0 + 4.0) / 4  # 0.5 * mean((V - R)^2)
CLIPPED_V_LOSS = 0.5 * (0.81 + 0.25 + 3.24 + 4.0) / 4
ENTROPY = jnp.array([0.5, 1.0, 1.5, 1.0])


def _loss(**kw):  # type: ignore[no-untyped-def]
    args = dict(clip_eps=0.2, clip_value=False, vf_coef=0.5, ent_coef=0.01, normalize_adv=False)
    args.update(kw)
    return losses.ppo_loss(
        LOG_PROB, OLD_LOG_PROB, ADV, VALUES, OLD_VALUES, RETURNS, ENTROPY, **args
    )


# --------------------------------------------------------------------------- the loss
def test_clipped_surrogate_takes_the_pessimistic_term_in_every_corner():
    # min(r A, clip(r, 0.8, 1.2) A): 1.2 (clipped), 0.5, -1.5, -0.8 (clipped); mean -0.15
    loss = losses.policy_loss(LOG_PROB, OLD_LOG_PROB, ADV, 0.2)
    assert float(loss) == pytest.approx(0.15, abs=1e-6)


@pytest.mark.full
def test_clipped_surrogate_gradient_is_zero_where_the_clip_binds():
    grad = jax.grad(losses.policy_loss)(LOG_PROB, OLD_LOG_PROB, ADV, 0.2)
    # d(-mean(r A))/d log_prob = -r A / 4 where unclipped: -0.5/4 and 1.5/4
    np.testing.assert_allclose(grad, [0.0, -0.125, 0.375, 0.0], atol=1e-6)


def test_value_loss_plain_and_clipped_by_hand():
    # plain errors (V - R)^2: 0.81, 0.25, 0.0, 4.0 -> 0.5 * mean = 0.6325
    plain = losses.value_loss(VALUES, OLD_VALUES, RETURNS, None)
    assert float(plain) == pytest.approx(0.6325, abs=1e-6)
    assert PLAIN_V_LOSS == pytest.approx(0.6325)
    # clipped V: 1.1, 2.2, 1.2, 0.8 -> errors 0.81, 0.09, 3.24, 1.44; the larger of each
    # pair: 0.81, 0.25, 3.24, 4.0 -> 1.0375
    clipped = losses.value_loss(VALUES, OLD_VALUES, RETURNS, 0.2)
    assert float(clipped) == pytest.approx(1.0375, abs=1e-6)
    assert CLIPPED_V_LOSS == pytest.approx(1.0375)


def test_ppo_loss_is_the_weighted_sum_of_its_parts():
    total, aux = _loss()
    kl = np.mean([0.5 - math.log(1.5), -0.5 - math.log(0.5)] * 2)
    assert float(aux["policy_loss"]) == pytest.approx(0.15, abs=1e-6)
    assert float(aux["value_loss"]) == pytest.approx(PLAIN_V_LOSS, abs=1e-6)
    assert float(aux["entropy"]) == pytest.approx(1.0, abs=1e-6)  # the mean entropy
    assert float(aux["approx_kl"]) == pytest.approx(kl, abs=1e-6)
    assert float(total) == pytest.approx(0.15 + 0.5 * 0.6325 - 0.01 * 1.0, abs=1e-6)


def test_ppo_loss_entropy_bonus_lowers_the_loss():
    no_bonus, _ = _loss(ent_coef=0.0)
    total, _ = _loss(ent_coef=0.2)
    assert float(no_bonus - total) == pytest.approx(0.2 * 1.0, abs=1e-6)
    # its gradient: -ent_coef / n per sample's entropy
    grad = jax.grad(
        lambda e: losses.ppo_loss(
            LOG_PROB, OLD_LOG_PROB, ADV, VALUES, OLD_VALUES, RETURNS, e,
            clip_eps=0.2, clip_value=False, vf_coef=0.5, ent_coef=0.2, normalize_adv=False,
        )[0]
    )(ENTROPY)  # fmt: skip
    np.testing.assert_allclose(grad, [-0.05] * 4, atol=1e-7)


def test_ppo_loss_clip_value_and_vf_coef():
    total, aux = _loss(clip_value=True, vf_coef=2.0, ent_coef=0.0)
    assert float(aux["value_loss"]) == pytest.approx(CLIPPED_V_LOSS, abs=1e-6)
    assert float(total) == pytest.approx(0.15 + 2.0 * 1.0375, abs=1e-6)
    # clip_value uses clip_eps: a wide clip leaves the plain loss
    _, wide = _loss(clip_value=True, clip_eps=10.0)
    assert float(wide["value_loss"]) == pytest.approx(PLAIN_V_LOSS, abs=1e-6)


def test_ppo_loss_normalises_the_advantages_first():
    # ADV has mean 0 and std 1 already: normalising changes nothing...
    same, _ = _loss(normalize_adv=True)
    assert float(same) == pytest.approx(float(_loss()[0]), abs=1e-6)
    # ...while 2 * ADV + 3 normalises back to ADV
    total, aux = losses.ppo_loss(
        LOG_PROB, OLD_LOG_PROB, 2 * ADV + 3, VALUES, OLD_VALUES, RETURNS, ENTROPY,
        clip_eps=0.2, clip_value=False, vf_coef=0.5, ent_coef=0.01, normalize_adv=True,
    )  # fmt: skip
    assert float(aux["policy_loss"]) == pytest.approx(0.15, abs=1e-6)
    assert float(total) == pytest.approx(float(same), abs=1e-6)


# ------------------------------------------------------------------ minibatch shuffle
T, N, MB = 4, 3, 3


def _rollout():  # type: ignore[no-untyped-def]
    """Time-major leaves whose entries name their flat sample ``t * N + n``."""
    ids = jnp.arange(T * N).reshape(T, N)
    return {"id": ids, "obs": jnp.stack([ids * 10, ids * 10 + 1], axis=-1).astype(jnp.float32)}


def test_minibatch_shapes():
    mbs = ppo.shuffle_minibatches(jax.random.key(0), _rollout(), MB)
    assert mbs["id"].shape == (MB, T * N // MB)
    assert mbs["obs"].shape == (MB, T * N // MB, 2)
    assert mbs["obs"].dtype == jnp.float32


def test_minibatches_are_one_permutation_of_every_sample():
    key = jax.random.key(1)
    mbs = ppo.shuffle_minibatches(key, _rollout(), MB)
    # the exact order: jax.random.permutation(key, T * N) of the time-major flat samples
    np.testing.assert_array_equal(mbs["id"].reshape(-1), jax.random.permutation(key, T * N))
    np.testing.assert_array_equal(np.sort(mbs["id"].reshape(-1)), np.arange(T * N))
    # every leaf is shuffled the same way: a sample's fields stay together
    np.testing.assert_array_equal(mbs["obs"][..., 0], mbs["id"] * 10)
    np.testing.assert_array_equal(mbs["obs"][..., 1], mbs["id"] * 10 + 1)


def test_minibatch_shuffle_is_deterministic_per_key_and_fresh_per_epoch():
    data = _rollout()
    a = ppo.shuffle_minibatches(jax.random.key(2), data, MB)["id"]
    b = ppo.shuffle_minibatches(jax.random.key(2), data, MB)["id"]
    np.testing.assert_array_equal(a, b)
    epochs = [
        np.asarray(ppo.shuffle_minibatches(k, data, MB)["id"])
        for k in jax.random.split(jax.random.key(2), 4)  # as the update splits its epoch key
    ]
    for e in epochs:  # every sample once per epoch
        np.testing.assert_array_equal(np.sort(e.reshape(-1)), np.arange(T * N))
    assert len({e.tobytes() for e in epochs}) == 4  # a new order each epoch


def test_minibatch_shuffle_jits_and_keeps_the_rollout_tuple():
    data = _rollout()
    rollout = (data["obs"], data["id"].astype(jnp.float32), -data["id"])
    mbs = jax.jit(ppo.shuffle_minibatches, static_argnums=2)(jax.random.key(3), rollout, 2)
    obs, adv, ret = mbs
    assert obs.shape == (2, 6, 2) and adv.shape == ret.shape == (2, 6)
    np.testing.assert_array_equal(adv, -ret)


# --------------------------------------------------------------- rollout statistics
def _traj() -> ppo.Transition:
    """3 steps x 2 envs; episodes end at (0, 1) [return 5, 10 steps], (1, 0) [return 2,
    4 steps, diverged] and (2, 1) [return 7, 3 steps]."""
    done = jnp.array([[False, True], [True, False], [False, True]])
    zeros = jnp.zeros((3, 2))
    return ppo.Transition(
        obs=zeros[..., None],
        critic_extra=zeros[..., :0],
        action=zeros.astype(jnp.int32),
        log_prob=zeros,
        value=zeros,
        next_value=zeros,
        reward=zeros,
        terminated=done,
        done=done,
        final_return=jnp.array([[99.0, 5.0], [2.0, 99.0], [99.0, 7.0]]),  # 99: not ended
        final_length=jnp.array([[50, 10], [4, 50], [50, 3]]),
        diverged=jnp.array([[False, False], [True, False], [False, False]]),
    )


def test_episode_stats_count_only_ended_episodes():
    ep = jax.device_get(ppo.episode_stats(_traj()))
    assert int(ep["n"]) == 3
    assert float(ep["ret_sum"]) == pytest.approx(14.0)
    assert float(ep["ret_max"]) == pytest.approx(7.0)
    assert int(ep["len_sum"]) == 17
    assert int(ep["diverged"]) == 1


def test_chunk_metrics_by_hand():
    ep = ppo.episode_stats(_traj())
    none = jax.tree.map(jnp.zeros_like, ep)
    stacked = jax.tree.map(lambda a, b: jnp.stack([a, b]), ep, none)  # 2 updates
    loss = {k: jnp.array([1.0, 2.0]) for k in ppo.LOSS_METRICS}
    rs = ppo.RunnerState(*([None] * 7), jnp.int32(96), jnp.int32(3), jnp.int32(2))
    m = jax.device_get(ppo.chunk_metrics(rs, {**stacked, **loss}))
    assert (int(m["env_steps"]), int(m["episodes"]), int(m["episodes_in_chunk"])) == (96, 3, 3)
    assert float(m["mean_return"]) == pytest.approx(14.0 / 3)
    assert float(m["max_return"]) == pytest.approx(7.0)
    assert float(m["mean_length"]) == pytest.approx(17.0 / 3)
    assert int(m["diverged"]) == 1
    assert all(float(m[k]) == 2.0 for k in ppo.LOSS_METRICS)  # the last update's
    empty = jax.device_get(
        ppo.chunk_metrics(rs, {**jax.tree.map(lambda x: x[1:], stacked), **loss})
    )
    assert math.isnan(empty["mean_return"]) and math.isnan(empty["max_return"])
    assert math.isnan(empty["mean_length"]) and int(empty["episodes_in_chunk"]) == 0
