"""HexapodJoystick-v0: an observation free of privileged quantities, the command process,
the velocity the reward tracks. (The public battery runs on it in tests/test_battery.py,
under the C engine in the default tier and under MJX in the full tier.)"""

from __future__ import annotations

import math
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import jaxenvs
from jaxenvs.config import ConfigError
from jaxenvs.tasks.hexapod.joystick import (
    HexapodJoystick,
    JoystickConfig,
    heading_velocity,
    sample_command,
)
from jaxenvs.testing import check_engine_parity


@pytest.fixture(scope="module")
def env() -> HexapodJoystick:
    made = jaxenvs.make("HexapodJoystick-v0", physics="c", command_interval=3)
    assert isinstance(made, HexapodJoystick)
    return made


#: the gap's config: actions delayed by 0-2 steps, sensor biases
GAP = {"action_delay_max": 2, "joint_bias": 0.02, "gyro_bias": 0.03}


@pytest.fixture(scope="module")
def gap_env() -> HexapodJoystick:
    made = jaxenvs.make("HexapodJoystick-v0", physics="c", command_interval=3, **GAP)
    assert isinstance(made, HexapodJoystick)
    return made


_PROGRAMS: dict[tuple[int, str], Any] = {}


def _jit(env: HexapodJoystick, name: str) -> Any:
    """``env``'s ``reset``, ``step`` or vmapped reset (``vreset``), jitted once per module:
    an eager call compiles each of its operations on its own, several seconds here."""
    if (id(env), name) not in _PROGRAMS:
        fn = {"reset": env.reset, "step": env.step, "vreset": jax.vmap(env.reset)}[name]
        _PROGRAMS[id(env), name] = jax.jit(fn)
    return _PROGRAMS[id(env), name]


def _key_of_delay(env: HexapodJoystick, delay: int) -> jax.Array:
    """A reset key whose env draws ``delay``."""
    keys = jax.random.split(jax.random.key(11), 64)
    drawn = np.asarray(_jit(env, "vreset")(keys).extras.delay)
    return keys[int(np.flatnonzero(drawn == delay)[0])]


@pytest.fixture(scope="module")
def walked(env):
    """A state after 10 steps of random actions."""
    step = _jit(env, "step")
    state = _jit(env, "reset")(jax.random.key(3))
    for i in range(10):
        state = step(state, jax.random.uniform(jax.random.key(i), (18,), minval=-0.5, maxval=0.5))
    return state


def _yaw_quat(yaw: float) -> jax.Array:
    return jnp.array([math.cos(yaw / 2), 0.0, 0.0, math.sin(yaw / 2)])


def _quat_mul(a: jax.Array, b: jax.Array) -> jax.Array:
    w1, x1, y1, z1 = a
    w2, x2, y2, z2 = b
    return jnp.stack(
        [
            w1 * w2 - x1 * x2 - y1 * y2 - z1 * z2,
            w1 * x2 + x1 * w2 + y1 * z2 - z1 * y2,
            w1 * y2 - x1 * z2 + y1 * w2 + z1 * x2,
            w1 * z2 + x1 * y2 - y1 * x2 + z1 * w2,
        ]
    )


def _moved(data, dx: float, dy: float, yaw: float):
    """``data`` with the robot turned by ``yaw`` about the world z axis through the origin
    and shifted by (dx, dy): its world position, heading, world velocity and the contact
    solver's warm start (its free-joint linear part) change; what it senses on board does
    not."""
    c, s = math.cos(yaw), math.sin(yaw)
    rot = jnp.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
    pos = rot @ data.qpos[:3] + jnp.array([dx, dy, 0.0])
    quat = _quat_mul(_yaw_quat(yaw), data.qpos[3:7])
    qpos = jnp.concatenate([pos, quat, data.qpos[7:]])
    qvel = data.qvel.at[:3].set(rot @ data.qvel[:3])  # the angular part is in the body frame
    warm = data.qacc_warmstart.at[:3].set(rot @ data.qacc_warmstart[:3])
    return data.replace(qpos=qpos, qvel=qvel, qacc_warmstart=warm)


def test_observation_ignores_world_position_and_yaw(env, walked):
    task = env.task_state(walked.data, walked.extras)
    obs = env.observation(env.robot.sense(walked.data), task)
    for dx, dy, yaw in ((3.0, -2.0, 0.0), (0.0, 0.0, 1.3), (-5.0, 7.0, -2.5)):
        moved = _moved(walked.data, dx, dy, yaw)
        assert not np.allclose(moved.qpos[:7], walked.data.qpos[:7])
        np.testing.assert_allclose(
            env.observation(env.robot.sense(moved), task), obs, atol=1e-5, rtol=1e-5
        )


@pytest.mark.parametrize(("contact", "isotropic"), [({}, True), ({"cone": "pyramidal"}, False)])
def test_default_contact_does_not_depend_on_the_heading(contact, isotropic):
    """Under MuJoCo C, the robot turned by 1.3 rad and moved, with the same servo commands,
    observes what it observed unturned over 5 control steps (within 2e-3) with the default
    contact (the elliptic cone, Newton's converged solve); the pyramidal cone's edges are
    fixed in the floor's frame, so there it does not."""
    env = jaxenvs.make("HexapodJoystick-v0", physics="c", **contact)
    step = jax.jit(env.step)
    state = jax.jit(env.reset)(jax.random.key(3))
    actions = jax.random.uniform(jax.random.key(4), (15, 18), minval=-0.5, maxval=0.5)
    for action in actions[:10]:
        state = step(state, action)
    turned = state.replace(data=_moved(state.data, 0.7, -0.4, 1.3))
    gap = 0.0
    for action in actions[10:]:
        state, turned = step(state, action), step(turned, action)
        gap = max(gap, float(jnp.max(jnp.abs(state.obs - turned.obs))))
    assert (gap <= 2e-3) == isotropic, gap


def test_observation_reads_only_what_the_robot_measures(env, walked):
    readings = env.robot.sense(walked.data)
    onboard = {name: readings[name] for name in env.robot.observable() if name in readings}
    assert set(readings) - set(onboard) == {"torso_vel", "torso_pos"}
    task = env.task_state(walked.data, walked.extras)
    np.testing.assert_array_equal(env.observation(onboard, task), env.observation(readings, task))
    # the observation's tail is the last action and the command
    np.testing.assert_array_equal(walked.obs[-3:], walked.extras.command)
    np.testing.assert_array_equal(walked.obs[-21:-3], walked.extras.actions[0])


@pytest.mark.parametrize("delay", [0, 1, 2])
def test_delay_applies_the_action_of_d_steps_ago(env, gap_env, delay):
    """From the same key, the delayed env under actions a_t moves exactly as the undelayed
    one under a_{t-d} (zeros before): the gap's draws leave the reset's other draws alone."""
    step, plain_step = _jit(gap_env, "step"), _jit(env, "step")
    key = _key_of_delay(gap_env, delay)
    state, plain = _jit(gap_env, "reset")(key), _jit(env, "reset")(key)
    assert int(state.extras.delay) == delay
    actions = jax.random.uniform(jax.random.key(7), (5, 18), minval=-0.5, maxval=0.5)
    for t in range(5):
        state = step(state, actions[t])
        plain = plain_step(plain, actions[t - delay] if t >= delay else jnp.zeros(18))
        np.testing.assert_array_equal(state.data.qpos, plain.data.qpos)
        np.testing.assert_array_equal(state.data.qvel, plain.data.qvel)
        # the observation holds the last three actions the policy gave, the newest first
        history = [actions[t - i] if t >= i else jnp.zeros(18) for i in range(3)]
        np.testing.assert_array_equal(state.obs[42:96], jnp.concatenate(history))
        np.testing.assert_array_equal(state.obs[-3:], state.extras.command)


def test_delay_and_biases_drawn_per_env_from_the_key(env, gap_env):
    keys = jax.random.split(jax.random.key(2), 300)
    extras = _jit(gap_env, "vreset")(keys).extras
    delay, bias = np.asarray(extras.delay), np.asarray(extras.bias)
    counts = np.bincount(delay, minlength=3)
    assert len(counts) == 3 and np.all(counts > 70)  # uniform in 0..2: 100 each
    # constant offsets on the joint angles (0.02 rad) and the gyro (0.03 rad/s) only
    assert np.all(np.abs(bias[:, :18]) <= 0.02) and np.abs(bias[:, :18]).max() > 0.019
    assert np.all(np.abs(bias[:, 39:]) <= 0.03) and np.abs(bias[:, 39:]).max() > 0.029
    assert np.all(bias[:, 18:39] == 0.0)
    assert len(np.unique(bias[:, 0])) == len(keys)
    again = _jit(gap_env, "vreset")(keys).extras
    np.testing.assert_array_equal(again.delay, delay)
    np.testing.assert_array_equal(again.bias, bias)
    other = _jit(gap_env, "vreset")(jax.random.split(jax.random.key(3), 300)).extras
    assert not np.array_equal(other.delay, delay)
    # the plain env: no delay, no bias, the observation of the last action only
    plain = _jit(env, "vreset")(keys[:8])
    assert np.all(np.asarray(plain.extras.delay) == 0) and not np.any(plain.extras.bias)
    assert env.observation_size == 63 and plain.obs.shape == (8, 63)
    assert gap_env.observation_size == 99


def test_biases_offset_the_observed_sensors(gap_env):
    state = _jit(gap_env, "reset")(jax.random.key(4))
    state = _jit(gap_env, "step")(state, jnp.full(18, 0.1))
    task = gap_env.task_state(state.data, state.extras)
    clean = gap_env.observation(gap_env.robot.sense(state.data), task)
    np.testing.assert_allclose(state.obs[:42] - clean[:42], state.extras.bias, atol=1e-6)
    np.testing.assert_array_equal(state.obs[42:], clean[42:])


def test_commands_redrawn_on_schedule_from_the_key(env):
    step = _jit(env, "step")

    def commands(key: jax.Array) -> np.ndarray:
        state = _jit(env, "reset")(key)
        out = [np.asarray(state.extras.command)]
        for _ in range(9):
            state = step(state, jnp.zeros(18))
            out.append(np.asarray(state.extras.command))
        return np.stack(out)

    first = commands(jax.random.key(0))
    # command_interval=3: held for 3 steps, then redrawn (steps 3, 6, 9)
    for block in range(3):
        held = first[3 * block : 3 * block + 3]
        np.testing.assert_array_equal(held, np.broadcast_to(held[0], held.shape))
        assert not np.array_equal(first[3 * block], first[3 * block + 3])
    np.testing.assert_array_equal(commands(jax.random.key(0)), first)
    assert not np.array_equal(commands(jax.random.key(1)), first)


def test_commands_cover_the_ranges_and_zero():
    config = JoystickConfig(zero_probability=0.2)
    u = jax.random.uniform(jax.random.key(0), (4000, 4))
    cmd = np.asarray(jax.vmap(lambda x: sample_command(x, config))(u))
    zero = np.all(cmd == 0.0, axis=1)
    assert 0.17 < zero.mean() < 0.23
    for axis, (low, high) in enumerate((config.vx_range, config.vy_range, config.yaw_range)):
        moving = cmd[~zero, axis]
        assert low <= moving.min() < low + 0.05 * (high - low)
        assert high - 0.05 * (high - low) < moving.max() <= high
    never = JoystickConfig(zero_probability=0.0)
    assert not np.any(np.all(np.asarray(jax.vmap(lambda x: sample_command(x, never))(u)) == 0, 1))


def test_zero_commands_occur_at_reset(env):
    states = _jit(env, "vreset")(jax.random.split(jax.random.key(5), 400))
    zero = np.all(np.asarray(states.extras.command) == 0.0, axis=1)
    assert 0.04 < zero.mean() < 0.17  # zero_probability 0.1


def test_heading_velocity():
    yaw = math.pi / 2
    quat = _yaw_quat(yaw)
    p0 = jnp.array([1.0, 2.0, 0.13])
    # 0.01 m along the heading (world +y) and 0.005 m to its left (world -x) in 0.05 s
    p1 = p0 + jnp.array([-0.005, 0.01, 0.0])
    v = heading_velocity(p0, quat, p1, quat, 0.05)
    np.testing.assert_allclose(v, [0.2, 0.1, 0.0], atol=1e-6)
    # turning across +-pi: the yaw rate is the short way round
    turned = heading_velocity(p0, _yaw_quat(math.pi - 0.01), p0, _yaw_quat(-math.pi + 0.01), 0.05)
    np.testing.assert_allclose(turned[2], 0.02 / 0.05, rtol=1e-4)


@pytest.mark.parametrize(
    "field, value",
    [("vx_range", (0.4, -0.4)), ("zero_probability", 1.5), ("command_interval", 0)],
)
def test_bad_config_is_named(field, value):
    with pytest.raises(ConfigError, match=field):
        JoystickConfig(**{field: value}).validate()


@pytest.mark.full
@pytest.mark.parametrize("gap", [{}, GAP], ids=["plain", "gap"])
def test_engine_parity_in_the_air(gap):
    """MJX and MuJoCo C agree step by step before the feet touch down (on the ground the
    solvers part from the first contact, as for the walker: tests/test_cengine.py), with
    and without the delayed actions and sensor biases."""
    check_engine_parity("HexapodJoystick-v0", steps=3, init_height=0.3, **gap)
