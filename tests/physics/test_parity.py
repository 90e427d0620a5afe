"""Parity of each env's step with MuJoCo C (``mujoco.mj_step``, float64, on the host).

Each case runs on MJX (``physics="mjx"``: the engine these tolerances were measured for)
and on the engine ``jaxenvs.make`` picks here (the C engine on a CPU, whose float32 state
between control steps drifts no more than MJX's float32 arithmetic). Default tier: every
case on the picked engine, and CartpoleBalance-v0 on MJX; full tier: the other MJX cases
(each costs an MJX compile).

For every case: reset the env, copy its state (qpos, qvel, mocap) into a host ``MjData``
of the same MJCF (with the env's default params written into the host model), then for
100 control steps apply the same random actions to both: the env through ``env.step``,
the host by copying the ``ctrl`` the env applied (``state.data.ctrl``) and running
``substeps`` calls of ``mj_step``. Positions and velocities must agree within the case's
tolerance after every control step. A second host run with the motor gear off by 1%
must NOT agree, which shows the tolerance is tight enough to catch a model mistake.

This guards what no reward curve reveals: a wrong integrator, timestep, substep count,
actuator mapping or a stage skipped in a hand-ordered MJX step.

Adding a robot is one ``ParityCase`` in ``BASE_CASES``. The harness assumes the task holds
``ctrl`` constant over a control step (``Sim.step``) and
keeps randomisable model fields in ``params.model``; a task whose controller runs at the
physics rate (``Sim.step_controlled``, e.g. ``CartpoleStayUp-v0``) needs a host mirror
of that controller and is not covered here.

Tolerances: the env runs in float32 (JAX's default), the host in float64, so the two
drift apart by float32 rounding (about 1e-7 relative per operation) amplified by the
dynamics' sensitivity over 100 steps. Each tolerance is about 10x the largest drift
measured on two seeds of the case (noted beside it): room for another machine's float
rounding, yet 100x or more under the drift a 1% gear error produces (>= 8e-3 in qpos).
"""

from __future__ import annotations

import copy
import dataclasses
from typing import Any

import jax
import mujoco
import numpy as np
import pytest

import jaxenvs
from jaxenvs.actions import random_actions

STEPS = 100


@dataclasses.dataclass(frozen=True)
class ParityCase:
    """One env id to check against MuJoCo C.

    Attributes:
      env_id: a registered id.
      qpos_atol, qvel_atol: absolute tolerances on positions and velocities.
      overrides: config overrides for ``jaxenvs.make``.
      seed: drives the reset and the actions.
    """

    env_id: str
    qpos_atol: float
    qvel_atol: float
    overrides: tuple[tuple[str, Any], ...] = ()
    seed: int = 0
    physics: str = "auto"

    def __str__(self) -> str:
        return f"{self.env_id}-{self.physics}"


BASE_CASES = [
    # measured over 100 steps (seeds 0, 1): drift qpos <= 1.8e-7, qvel <= 7.8e-7;
    # a 1% gear error: qpos >= 8e-3
    ParityCase(
        "CartpoleBalance-v0",
        qpos_atol=2e-6,
        qvel_atol=1e-5,
        overrides=(("cart_limit", 1e3),),
        seed=1,  # seed 0's pole barely leaves upright in 1 s
    ),
    # 0.02 s Euler steps, Discrete(2) mapped to ctrl -1 / +1; the pole spins through
    # several turns (|angle| up to 11 rad): drift qpos <= 4.9e-6, qvel <= 9.5e-6
    ParityCase("CartPole-v0", qpos_atol=5e-5, qvel_atol=1e-4, overrides=(("x_threshold", 1e3),)),
    # angles up to 9 rad, velocities up to 22 rad/s: drift qpos <= 2.9e-6, qvel <= 2.5e-6
    ParityCase("Reacher-v0", qpos_atol=3e-5, qvel_atol=3e-5),
    # position servos, gravity, no contacts: drift qpos <= 4.1e-7, qvel <= 8.1e-6;
    # a 1% gear error: qpos >= 2.8e-2 (the walker's contacts: tests/test_hexapod.py)
    ParityCase("HexapodOneLeg-v0", qpos_atol=5e-6, qvel_atol=1e-4),
]
#: MJX cases in the default tier (the cheapest MJX compile); the others run in the full tier
DEFAULT_MJX = ("CartpoleBalance-v0",)
CASES = [
    *BASE_CASES,
    *(
        pytest.param(
            dataclasses.replace(case, physics="mjx"),
            marks=() if case.env_id in DEFAULT_MJX else pytest.mark.full,
            id=f"{case.env_id}-mjx",
        )
        for case in BASE_CASES
    ),
]


def _host_model(env: Any, gear_factor: float = 1.0) -> mujoco.MjModel:
    """The env's host model with its default params written in (optionally mis-geared)."""
    model = copy.deepcopy(env.sim.mj_model)
    for name, value in getattr(env.default_params, "model", {}).items():
        getattr(model, name)[...] = np.asarray(value, np.float64)
    model.actuator_gear[:] *= gear_factor
    return model


def _host_trajectory(env: Any, state0: Any, ctrls: np.ndarray, gear_factor: float = 1.0):
    model = _host_model(env, gear_factor)
    data = mujoco.MjData(model)
    data.qpos[:] = np.asarray(state0.data.qpos, np.float64)
    data.qvel[:] = np.asarray(state0.data.qvel, np.float64)
    if model.nmocap:
        data.mocap_pos[:] = np.asarray(state0.data.mocap_pos, np.float64)
        data.mocap_quat[:] = np.asarray(state0.data.mocap_quat, np.float64)
    qpos, qvel = [], []
    for ctrl in ctrls:
        data.ctrl[:] = ctrl
        for _ in range(env.sim.substeps):
            mujoco.mj_step(model, data)
        qpos.append(data.qpos.copy())
        qvel.append(data.qvel.copy())
    return np.array(qpos), np.array(qvel)


def run_case(case: ParityCase):
    """(case, env, initial state, MJX qpos[T], MJX qvel[T], host qpos[T], host qvel[T],
    ctrls[T]) for ``STEPS`` control steps of random actions."""
    overrides = dict(case.overrides)
    env = jaxenvs.make(case.env_id, episode_length=10 * STEPS, physics=case.physics, **overrides)
    reset_key, action_key = jax.random.split(jax.random.key(case.seed))
    state0 = jax.jit(env.reset)(reset_key)
    step = jax.jit(env.step)
    actions = [random_actions(env, k) for k in jax.random.split(action_key, STEPS)]
    state, qpos, qvel, ctrls = state0, [], [], []
    for a in actions:
        state = step(state, a)
        qpos.append(np.asarray(state.data.qpos, np.float64))
        qvel.append(np.asarray(state.data.qvel, np.float64))
        ctrls.append(np.asarray(state.data.ctrl, np.float64))
    ctrls_arr = np.array(ctrls)
    host_qpos, host_qvel = _host_trajectory(env, state0, ctrls_arr)
    return case, env, state0, np.array(qpos), np.array(qvel), host_qpos, host_qvel, ctrls_arr


@pytest.fixture(scope="module", params=CASES, ids=str)
def parity_run(request):
    return run_case(request.param)


@pytest.mark.full
def test_step_matches_mujoco_c(parity_run):
    case, _, _, qpos, qvel, host_qpos, host_qvel, _ = parity_run
    assert np.abs(host_qpos[-1] - host_qpos[0]).max() > 0.1  # a trajectory, not a rest
    err_q = np.abs(qpos - host_qpos).max(axis=1)
    err_v = np.abs(qvel - host_qvel).max(axis=1)
    worst_q, worst_v = int(err_q.argmax()), int(err_v.argmax())
    assert err_q.max() <= case.qpos_atol, f"qpos off by {err_q.max():.2e} at step {worst_q}"
    assert err_v.max() <= case.qvel_atol, f"qvel off by {err_v.max():.2e} at step {worst_v}"


def test_tolerance_catches_a_one_percent_gear_error(parity_run):
    case, env, state0, qpos, qvel, _, _, ctrls = parity_run
    bad_qpos, bad_qvel = _host_trajectory(env, state0, ctrls, gear_factor=1.01)
    off_q = np.abs(qpos - bad_qpos).max()
    off_v = np.abs(qvel - bad_qvel).max()
    assert off_q > case.qpos_atol or off_v > case.qvel_atol, (off_q, off_v)
