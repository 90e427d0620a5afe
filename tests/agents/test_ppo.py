"""PPO: hand-computed GAE and losses (the clipped surrogate, the value loss plain and
clipped, the entropy bonus, advantage normalisation, approx KL), distributions, running
statistics (one stream and merged across devices), the minibatch shuffle, the episode and
chunk figures of a rollout, configs and what a device count makes of them, and short
CartPole runs whose learning signal must move (default tier) and which must reach a
threshold when run longer (full tier). Several devices: tests/agents/test_ppo_devices.py."""

from __future__ import annotations

import dataclasses
import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import jaxenvs
from jaxenvs.agents import losses, ppo
from jaxenvs.agents.base import CHUNK_METRICS, make_train
from jaxenvs.agents.networks import (
    ActorCritic,
    categorical_entropy,
    categorical_log_prob,
    gaussian_entropy,
    gaussian_log_prob,
)
from jaxenvs.agents.normalize import merge_sums, shifted_sums, stats_empty
from jaxenvs.config import ConfigError, apply_overrides
from jaxenvs.core import BatchedEnv, sharding
from jaxenvs.run import runner

# ----------------------------------------------------------------------------- GAE
GAMMA, LAM = 0.9, 0.8
GAE_REWARDS = jnp.array([1.0, 2.0, 3.0])
GAE_VALUES = jnp.array([0.5, 1.0, 1.5])
GAE_NEXT = jnp.array([1.0, 1.5, 2.0])  # no episode end: next_values[t] = values[t + 1]


def _gae(next_values=GAE_NEXT, terminated=(0, 0, 0), done=(0, 0, 0)):  # type: ignore[no-untyped-def]
    return losses.gae(
        GAE_REWARDS, GAE_VALUES, next_values, jnp.array(terminated), jnp.array(done), GAMMA, LAM
    )


def test_gae_without_episode_end():
    # deltas: 1 + .9*1 - .5 = 1.4; 2 + .9*1.5 - 1 = 2.35; 3 + .9*2 - 1.5 = 3.3
    # A2 = 3.3; A1 = 2.35 + .72*3.3 = 4.726; A0 = 1.4 + .72*4.726 = 4.80272
    adv, ret = _gae()
    np.testing.assert_allclose(adv, [4.80272, 4.726, 3.3], rtol=1e-6)
    np.testing.assert_allclose(ret, np.array([4.80272, 4.726, 3.3]) + GAE_VALUES, rtol=1e-6)


def test_gae_bootstraps_on_truncation_from_the_final_observation():
    # step 1 is truncated; the value of its final_obs is 5.0 (not values[2] = 1.5):
    # delta1 = 2 + .9*5 - 1 = 5.5, and the trace stops: A1 = 5.5; A0 = 1.4 + .72*5.5 = 5.36
    adv, _ = _gae(next_values=jnp.array([1.0, 5.0, 2.0]), done=(0, 1, 0))
    np.testing.assert_allclose(adv, [5.36, 5.5, 3.3], rtol=1e-6)


def test_gae_does_not_bootstrap_on_termination():
    # step 1 terminates: delta1 = 2 - 1 = 1, A1 = 1; A0 = 1.4 + .72*1 = 2.12
    adv, _ = _gae(next_values=jnp.array([1.0, 5.0, 2.0]), terminated=(0, 1, 0), done=(0, 1, 0))
    np.testing.assert_allclose(adv, [2.12, 1.0, 3.3], rtol=1e-6)


def test_gae_batched_envs_are_independent():
    rewards = jnp.stack([GAE_REWARDS, 2 * GAE_REWARDS], axis=1)  # (T, 2 envs)
    values = jnp.stack([GAE_VALUES, GAE_VALUES], axis=1)
    nv = jnp.stack([GAE_NEXT, GAE_NEXT], axis=1)
    zeros = jnp.zeros((3, 2))
    adv, _ = losses.gae(rewards, values, nv, zeros, zeros, GAMMA, LAM)
    np.testing.assert_allclose(adv[:, 0], _gae()[0], rtol=1e-6)
    single, _ = losses.gae(
        2 * GAE_REWARDS, GAE_VALUES, GAE_NEXT, zeros[:, 0], zeros[:, 0], GAMMA, LAM
    )
    np.testing.assert_allclose(adv[:, 1], single, rtol=1e-6)


# --------------------------------------------------------------------------- the loss
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


def test_approx_kl_is_zero_for_equal_policies_and_positive_otherwise():
    lp = jnp.array([-0.1, -2.0, -0.7])
    assert float(losses.approx_kl(lp, lp)) == pytest.approx(0.0, abs=1e-7)
    assert float(losses.approx_kl(lp + jnp.array([0.3, -0.2, 0.1]), lp)) > 0.0


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


# ------------------------------------------------------------------- distributions
def test_categorical_log_prob_and_entropy():
    logits = jnp.array([0.0, math.log(3.0)])  # probabilities 0.25, 0.75
    assert float(categorical_log_prob(logits, jnp.array(1))) == pytest.approx(math.log(0.75))
    expected = -(0.25 * math.log(0.25) + 0.75 * math.log(0.75))
    assert float(categorical_entropy(logits)) == pytest.approx(expected, rel=1e-6)


def test_gaussian_log_prob_and_entropy():
    mean, log_std = jnp.zeros(2), jnp.array([0.0, math.log(2.0)])
    # dim 0: N(1; 0, 1); dim 1: N(2; 0, 4) -> both -0.5 - log(std) - 0.5 log(2 pi)
    lp = gaussian_log_prob(mean, log_std, jnp.array([1.0, 2.0]))
    expected = 2 * (-0.5 - 0.5 * math.log(2 * math.pi)) - math.log(2.0)
    assert float(lp) == pytest.approx(expected, rel=1e-6)
    ent = 2 * 0.5 * math.log(2 * math.pi * math.e) + math.log(2.0)
    assert float(gaussian_entropy(log_std)) == pytest.approx(ent, rel=1e-6)


def test_actor_critic_heads_and_initial_policy():
    obs = jnp.ones((7, 3))
    disc = ActorCritic(action_size=4, discrete=True)
    logits, value = disc.apply(disc.init(jax.random.key(0), obs[0]), obs)
    assert logits.shape == (7, 4) and value.shape == (7,)
    # output gain 0.01: the first policy is close to uniform
    assert float(jnp.abs(logits).max()) < 0.1
    cont = ActorCritic(action_size=2, discrete=False, log_std_init=-0.5)
    params = cont.init(jax.random.key(0), obs[0])
    (mean, log_std), value = cont.apply(params, obs)
    assert mean.shape == (7, 2) and value.shape == (7,)
    np.testing.assert_allclose(log_std, -0.5)


# ------------------------------------------------------------------ running stats
def test_running_stats_match_the_whole_stream():
    data = jax.random.normal(jax.random.key(1), (300, 3)) * jnp.array([1.0, 5.0, 0.1]) + 2.0
    stats = ppo.stats_init((3,))
    for batch in jnp.split(data, 6):
        stats = ppo.stats_update(stats, batch)
    np.testing.assert_allclose(stats.mean, data.mean(0), rtol=1e-4)
    np.testing.assert_allclose(stats.var, data.var(0), rtol=1e-3)
    z = ppo.normalize(stats, data, clip=10.0)
    np.testing.assert_allclose(z.mean(0), 0.0, atol=1e-3)


def test_running_stats_merged_across_devices_match_the_whole_stream():
    """Each "device" merges its own batches into an empty accumulator; their shifted sums
    (added as a psum adds them) merged into the shared statistics give those of one
    stream of every batch, and a device that saw nothing adds nothing."""
    data = jax.random.normal(jax.random.key(2), (4, 3, 50, 2)) * jnp.array([0.01, 30.0]) + 5.0
    shared = ppo.stats_update(ppo.stats_init((2,)), data[0, 0])  # what every device holds
    whole = shared
    parts = []
    for device in range(1, 4):
        acc = stats_empty((2,))
        for batch in data[device]:
            acc = ppo.stats_update(acc, batch)
            whole = ppo.stats_update(whole, batch)
        parts.append(shifted_sums(acc, shared.mean))
    parts.append(shifted_sums(stats_empty((2,)), shared.mean))  # a device with no samples
    summed = jax.tree.map(lambda *x: sum(x), *parts)
    merged = merge_sums(shared, summed)
    np.testing.assert_allclose(merged.n, whole.n, rtol=1e-6)
    np.testing.assert_allclose(merged.mean, whole.mean, rtol=1e-5, atol=1e-6)
    np.testing.assert_allclose(merged.var, whole.var, rtol=1e-4)
    unchanged = merge_sums(shared, shifted_sums(stats_empty((2,)), shared.mean))
    for a, b in zip(unchanged, shared, strict=True):
        np.testing.assert_allclose(a, b, rtol=1e-6)


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


# ------------------------------------------------------------------------ configs
def test_config_validation_names_the_key():
    with pytest.raises(ConfigError, match="num_minibatches"):
        apply_overrides(ppo.PPOConfig(), {"num_envs": 3, "num_steps": 5}, "test")
    with pytest.raises(ConfigError, match="gamma"):
        apply_overrides(ppo.PPOConfig(), {"gamma": 1.5}, "test")


def test_scaling_on_devices():
    """``on_devices``: the strong config of the whole batch a device count trains:
    ``strong`` keeps ``num_envs`` (split), ``weak`` multiplies it; a batch that does not
    split, or a share that ``num_minibatches`` does not divide, is refused by its sizes."""
    base = ppo.PPOConfig(num_envs=16, num_steps=8, num_minibatches=4)
    assert base.scaling == "strong"
    assert base.on_devices(4) == base
    weak = dataclasses.replace(base, scaling="weak")
    assert weak.on_devices(1) == base
    assert weak.on_devices(4) == dataclasses.replace(base, num_envs=64)
    assert weak.on_devices(4).steps_per_update == 4 * base.steps_per_update
    with pytest.raises(ValueError, match="num_envs=16 does not split over 3 devices"):
        base.on_devices(3)
    with pytest.raises(ValueError, match="num_minibatches=4 does not divide"):
        dataclasses.replace(base, num_steps=1).on_devices(8)  # 2 envs x 1 step a device
    assert weak.on_devices(3).num_envs == 48
    with pytest.raises(ConfigError, match="scaling"):
        apply_overrides(base, {"scaling": "both"}, "test")


def test_one_device_trainer_holds_no_collective():
    """Without a mesh, or on a mesh of one device, PPO is the one-device program: the
    same jaxpr, with no cross-device op in it."""
    env = jaxenvs.make("CartPole-v0")
    config = ppo.PPOConfig(total_steps=64, num_envs=4, num_steps=4, updates_per_chunk=1)
    plain = ppo.make_trainer(env, config)
    one = ppo.make_trainer(env, config, sharding.make_mesh(1))
    state = jax.eval_shape(plain.init, jax.random.key(0))
    text = str(jax.make_jaxpr(plain.chunk)(state))
    assert text == str(jax.make_jaxpr(one.chunk)(state))
    for op in ("psum", "pmax", "pmean", "all_gather", "axis_index"):
        assert op not in text, op


# ------------------------------------------------------------------- training runs
CARTPOLE = ppo.PPOConfig(
    total_steps=4 * 4096,
    num_envs=16,
    num_steps=64,
    updates_per_chunk=4,
    learning_rate=1e-3,
    clip_value=False,
    normalize_obs=False,
    normalize_rewards=True,
)


def _cartpole_run(config):
    env = jaxenvs.make("CartPole-v0")
    trainer = ppo.make_trainer(env, config)
    keys = jax.random.split(jax.random.key(0), 2)
    final, metrics = jax.jit(jax.vmap(make_train(trainer)))(keys)  # one program, 2 seeds
    return env, trainer, final, jax.device_get(metrics)


@pytest.fixture(scope="module")
def cartpole_run():
    """The first 2 chunks (8192 steps) of the run below: one program, 2 seeds."""
    return _cartpole_run(dataclasses.replace(CARTPOLE, total_steps=2 * 4096))


@pytest.mark.full
def test_short_cartpole_run_learns(cartpole_run):
    """The learning signal moves: each update improved its own surrogate objective, the
    policy left the uniform one, and the second chunk's episodes are longer."""
    _, trainer, _, metrics = cartpole_run
    assert set(CHUNK_METRICS) <= set(metrics)
    ret = np.asarray(metrics["mean_return"])  # (seeds, chunks)
    assert ret.shape == (2, trainer.num_chunks) == (2, 2)
    for key in ("mean_return", "loss", "policy_loss", "value_loss", "entropy", "approx_kl"):
        assert np.all(np.isfinite(np.asarray(metrics[key]))), key
    assert np.all(np.asarray(metrics["policy_loss"]) < 0)  # the clipped surrogate went up
    assert np.all(np.asarray(metrics["approx_kl"]) > 0)
    assert np.all(np.asarray(metrics["entropy"])[:, -1] < math.log(2) - 0.02)
    # random play lasts ~22 steps; after 4096 steps of training both seeds play longer
    assert np.all(ret[:, 1] > 1.5 * ret[:, 0]), ret
    np.testing.assert_array_equal(metrics["env_steps"][:, -1], 2 * 4096)


@pytest.mark.full  # training to a threshold
def test_short_cartpole_run_improves():
    _, trainer, _, metrics = _cartpole_run(CARTPOLE)
    assert set(CHUNK_METRICS) <= set(metrics)
    ret = np.asarray(metrics["mean_return"])  # (seeds, chunks)
    assert ret.shape == (2, trainer.num_chunks)
    assert np.all(np.isfinite(ret))
    # random play lasts ~22 steps; after 16k steps both seeds do far better
    assert np.all(ret[:, -1] > 2 * ret[:, 0]), ret
    np.testing.assert_array_equal(metrics["env_steps"][:, -1], CARTPOLE.total_steps)


@pytest.mark.full  # training to the README's threshold
def test_shipped_cartpole_config_solves_cartpole(tmp_path):
    """``jaxenvs train CartPole-v0 --algo ppo`` as the README runs it (the shipped config,
    seed 0): the greedy policy's mean return over 20 episodes is at least 475, the
    task's reward threshold (the shipped config reaches 500: benchmarks/RESULTS.md#ppo)."""
    resolved = runner.resolve_config("CartPole-v0", "ppo", None, train_overrides={"video": False})
    assert resolved.agent.total_steps == 131072  # the shipped file, not a shortened run
    summary = runner.train(resolved, tmp_path, quiet=True)
    assert summary["eval_episodes"] == 20 and not summary["interrupted"]
    assert summary["eval_mean_return"] >= 475.0, summary


def test_greedy_policy_acts_in_the_action_space():
    env = jaxenvs.make("CartPole-v0")
    trainer = ppo.make_trainer(env, dataclasses.replace(CARTPOLE, total_steps=4096))
    params = trainer.policy_params(trainer.init(jax.random.key(0)))
    obs = jax.vmap(env.reset)(jax.random.split(jax.random.key(3), 5)).obs
    act = jax.vmap(trainer.act, in_axes=(None, 0, None))(params, obs, jax.random.key(0))
    assert act.shape == (5,) and act.dtype == jnp.int32
    assert bool(jnp.all((act >= 0) & (act < env.action_size)))


@pytest.mark.full
def test_continuous_randomised_task_chunk_runs():
    env = jaxenvs.make("CartpoleBalance-v0", episode_length=50)
    config = dataclasses.replace(
        CARTPOLE, total_steps=8 * 16, num_envs=8, num_steps=16, updates_per_chunk=1, randomize=True
    )
    trainer = ppo.make_trainer(env, config)
    state = trainer.init(jax.random.key(0))
    # every env drew its own physics (domain randomisation)
    masses = state.env_state.params.model["body_mass"]
    assert masses.shape[0] == 8 and bool(jnp.any(masses[0] != masses[1]))
    state, metrics = jax.jit(trainer.chunk)(state)
    assert int(metrics["env_steps"]) == 128
    for key in ("loss", "entropy", "approx_kl"):
        assert np.isfinite(float(metrics[key])), key
    action = trainer.act(trainer.policy_params(state), state.env_state.obs[0], jax.random.key(1))
    assert action.shape == (1,) and float(jnp.abs(action).max()) <= 1.0


# ----------------------------------------------------------- asymmetric actor-critic
def test_critic_info_feeds_the_critic_alone():
    """``critic_info``: the critic's first layer takes the observation and the named
    metrics, the actor's the observation alone (its params as without them); a state's
    inputs are the metrics of the transition into it, zero at a fresh start, and a
    finished episode's bootstrap reads its last transition's (non-finite ones read as
    zero); a chunk trains with them and updates their statistics at every env step; the
    greedy policy needs none; an unknown key is refused by name."""
    env = jaxenvs.make("CartpoleStayUp-v0", episode_length=3)
    plain = ppo.PPOConfig(
        total_steps=16, num_envs=4, num_steps=4, updates_per_chunk=1, num_minibatches=2,
        actor_hidden=(8,), critic_hidden=(8,),
    )  # fmt: skip
    asym = dataclasses.replace(plain, critic_info=("command",))
    key = jax.random.key(0)
    rs0 = ppo.make_trainer(env, plain).init(key)
    trainer = ppo.make_trainer(env, asym)
    rs = trainer.init(key)
    obs_dim = env.observation_size
    assert rs.params["params"]["critic"]["Dense_0"]["kernel"].shape == (obs_dim + 1, 8)
    assert rs.params["params"]["actor"]["Dense_0"]["kernel"].shape == (obs_dim, 8)
    for a, b in zip(jax.tree.leaves(rs0.params["params"]["actor"]),
                    jax.tree.leaves(rs.params["params"]["actor"]), strict=True):  # fmt: skip
        np.testing.assert_array_equal(a, b)
    assert rs0.critic_stats is None

    benv = BatchedEnv(env, 4)
    state = benv.reset(jax.random.key(1))
    step = jax.jit(benv.step)
    state = step(state, jnp.full((4,), 3, jnp.int32))  # a command away from zero
    last = np.asarray(state.info["command"])
    assert np.all(last != 0)
    np.testing.assert_array_equal(
        ppo.critic_inputs(state.info, ("command",), state.time == 0)[:, 0], last
    )
    state = step(step(state, jnp.full((4,), 3, jnp.int32)), jnp.full((4,), 3, jnp.int32))
    assert np.all(np.asarray(state.time) == 0)  # truncated after 3 steps and reset
    final = ppo.critic_inputs(state.info, ("command",), False)[:, 0]
    assert np.all(np.asarray(final) != 0)  # the bootstrap's: the last transition's
    fresh = ppo.critic_inputs(state.info, ("command",), state.time == 0)
    np.testing.assert_array_equal(fresh, 0.0)  # a fresh start's: zero, as env.reset's

    n0 = float(rs.critic_stats.n)
    rs, metrics = jax.jit(trainer.chunk)(rs)
    assert np.isfinite(float(metrics["value_loss"]))
    assert float(rs.critic_stats.n) == pytest.approx(n0 + 4 * 4)  # every env, every step
    assert float(rs.critic_stats.mean[0]) != 0.0
    bad = {"episode_length": jnp.zeros(2, jnp.int32), "command": jnp.array([jnp.nan, 2.0])}
    np.testing.assert_array_equal(ppo.critic_inputs(bad, ("command",), False)[:, 0], [0, 2])
    act = trainer.act(trainer.policy_params(rs), state.obs[0], jax.random.key(2))
    assert act.shape == () and 0 <= int(act) < env.action_size
    with pytest.raises(ValueError, match="critic_info: nope not among"):
        ppo.make_trainer(env, dataclasses.replace(plain, critic_info=("nope",)))
