"""Does the hexapod's contact depend on its heading? And what does heading-free contact cost?

The same robot with the same servo commands is simulated twice under MuJoCo's C engine: as
it is (A) and turned by 1.3 rad about the vertical and moved by (0.7, -0.4) m (B). A floor
whose friction does not depend on the robot's heading gives B the same joint angles, joint
velocities, gravity direction and gyro readings as A; the friction pyramid's edges are
fixed in the floor's frame, so under ``cone="pyramidal"`` they differ.

Each setting (:class:`Setting`: solver, cone, CG iterations, line-search iterations,
impratio, noslip iterations, tolerance) is applied to ``HexapodJoystick-v0``'s own host model
(``jaxenvs.make(..., physics="c").sim.physics_mj_model``: the robot on its flat floor, six
foot-floor pairs, timestep 0.01 s, 5 substeps per control step; with the env's float32
params) and stepped with ``mujoco.mj_step``, the state
rounded to float32 after each control step as the env's state is. ``extra.loop_vs_env_qpos``
checks this loop against the env's own C engine step (``env.sim.step``, one control step at a
time from the env's state). Observations are the env's own (``env.observation`` of
``env.robot.sense``) with the same action history and command in A and B, so only the 42
sensor entries can differ. Scenarios:

* ``start``: A and B from the env's start pose (torso at 0.14 m, joints at the stance, at
  rest), driven by an open-loop tripod gait from t = 0.
* ``gait``: A walks the tripod gait for 1 s; B is A's state turned and moved (positions,
  free-joint velocity and the solver's warm start rotated); both walk on.
* ``random0..2``: as ``gait`` with smooth random servo commands (sums of sinusoids).

Figures per setting, the worst over the scenarios: ``obs_1``, ``obs_5`` (the largest
|obs_A - obs_B| one control step, and over the first five control steps, after the turn;
``isotropic``: ``obs_5`` <= 2e-3), ``joint_0p6s`` and ``joint_2s`` (the largest joint-angle
difference 0.6 s after the turn, and over 2 s); ``nudge_obs_5``, ``obs_5`` with B = A with one
joint nudged by 1e-9 rad instead of turned (how far the dynamics themselves carry a
rounding-sized difference); the solver's iterations (mean, max) along A; ``walked_m``, the
gait's distance in 2 s from the start; ``steps_per_cpu_s``, single-threaded ``mj_step`` calls
per CPU second of the tripod gait (thread time, the best of ``--rounds`` interleaved rounds)
and ``cost_vs_today``, the time of a step over today's; ``terrain_stand_range_m``, the range
of the torso's height while the robot stands (servos at the stance, seconds 1 to 3) on the
default generated terrain's top-level flat, rough-slope and obstacle tiles, the worst of the
three (on the plane, under 0.1 mm), and
``terrain_contacts``, the mean number of contacts there (several per foot on a heightfield).

    python benchmarks/contact_isotropy.py --json contact_isotropy_cpu2
"""

from __future__ import annotations

import argparse
import copy
import math
import os
import time
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
import results_io

import jaxenvs
from jaxenvs.robots.hexapod import LEGS
from jaxenvs.scenes import Scene
from jaxenvs.scenes.terrain import Terrain, generate

ENV_ID = "HexapodJoystick-v0"
TURN = 1.3  # rad about the vertical
SHIFT = np.array([0.7, -0.4, 0.0])  # m
TARGET = 2e-3  # the largest |obs_A - obs_B| allowed over 5 control steps
NUDGE = 1e-9  # rad on one joint: the dynamics' own sensitivity, for scale
WARM_STEPS = 20  # control steps (1 s) before the turn in the mid-gait scenarios
STEPS = 40  # control steps (2 s) after the turn


class Setting(NamedTuple):
    """A contact and solver setting (``mjOption`` fields)."""

    solver: str
    cone: str
    iterations: int
    ls_iterations: int
    impratio: float = 1.0
    noslip_iterations: int = 0
    tolerance: float = 1e-8


#: the first is today's. Newton for reference: MJX's Newton calls LAPACK (a Cholesky),
#: which the hexapod's MJCF avoids (benchmarks/NOTES.md, the "hexapod stall")
SETTINGS = (
    Setting("CG", "pyramidal", 6, 3),
    Setting("CG", "pyramidal", 50, 10),
    Setting("CG", "elliptic", 4, 3),
    Setting("CG", "elliptic", 6, 3),
    Setting("CG", "elliptic", 8, 3),
    Setting("CG", "elliptic", 12, 3),
    Setting("CG", "elliptic", 6, 3, noslip_iterations=3),
    Setting("CG", "elliptic", 16, 6),
    Setting("CG", "elliptic", 20, 6),
    Setting("CG", "elliptic", 20, 10),
    Setting("CG", "elliptic", 25, 10),
    Setting("CG", "elliptic", 30, 6),
    Setting("CG", "elliptic", 30, 10),
    Setting("CG", "elliptic", 30, 10, tolerance=1e-6),
    Setting("CG", "elliptic", 40, 10),
    Setting("CG", "elliptic", 50, 10),
    Setting("CG", "elliptic", 30, 10, impratio=10.0),
    Setting("Newton", "elliptic", 3, 3),
    Setting("Newton", "elliptic", 4, 6),
    Setting("Newton", "pyramidal", 4, 6),
)


class _State(NamedTuple):
    qpos: jax.Array
    qvel: jax.Array


def tripod(t: float) -> np.ndarray:
    """An open-loop tripod gait's action (18, in [-1, 1]) at time ``t`` (s): legs lf, rm,
    lr swing while rf, lm, rr push, 0.8 s a cycle."""
    group = np.array([0, 1, 0, 1, 0, 1])  # lf lm lr rf rm rr
    side = np.array([1, 1, 1, -1, -1, -1])
    phase = 2 * math.pi * t / 0.8 + math.pi * group
    hip = 0.5 * np.sin(phase) * side
    femur = 0.3 * np.maximum(0.0, np.cos(phase))
    tibia = -0.15 * np.maximum(0.0, np.cos(phase))
    return np.stack([hip, femur, tibia], axis=1).ravel()


def smooth_random(seed: int):  # type: ignore[no-untyped-def]
    """Smooth random actions: per joint a sum of three sinusoids (0.3 to 2 Hz)."""
    rng = np.random.default_rng(seed)
    freq = rng.uniform(0.3, 2.0, (3, 18))
    phase = rng.uniform(0, 2 * math.pi, (3, 18))
    amp = rng.uniform(0.1, 0.3, (3, 18))

    def action(t: float) -> np.ndarray:
        return np.clip(np.sum(amp * np.sin(2 * math.pi * freq * t + phase), axis=0), -1, 1)

    return action


def hexapod_model(env: Any) -> mujoco.MjModel:
    """The host model the env's C engine steps (``env.sim.physics_mj_model``: the robot on
    its flat floor, six foot-floor pairs, the task's solver options)."""
    m = env.sim.physics_mj_model
    if m.npair != len(LEGS):
        raise SystemExit(
            f"{ENV_ID}: expected {len(LEGS)} foot-floor pairs, the model has {m.npair}"
        )
    return m


def configured(base: mujoco.MjModel, setting: Setting, fields: dict[str, Any]) -> mujoco.MjModel:
    """A copy of ``base`` with ``setting``'s options and the env's params ``fields`` (its
    float32 masses, gains, frictions: the numbers the env's C engine applies)."""
    m = copy.deepcopy(base)
    for name, value in fields.items():
        getattr(m, name)[:] = np.asarray(value, np.float64)
    newton = setting.solver == "Newton"
    m.opt.solver = mujoco.mjtSolver.mjSOL_NEWTON if newton else mujoco.mjtSolver.mjSOL_CG
    elliptic = setting.cone == "elliptic"
    m.opt.cone = mujoco.mjtCone.mjCONE_ELLIPTIC if elliptic else mujoco.mjtCone.mjCONE_PYRAMIDAL
    m.opt.iterations = setting.iterations
    m.opt.ls_iterations = setting.ls_iterations
    m.opt.impratio = setting.impratio
    m.opt.noslip_iterations = setting.noslip_iterations
    m.opt.tolerance = setting.tolerance
    return m


def start(model: mujoco.MjModel, env: Any) -> mujoco.MjData:
    """The env's start pose at yaw 0: torso at ``init_height``, joints at the stance."""
    d = mujoco.MjData(model)
    d.qpos[:] = 0.0
    d.qpos[2] = env.config.init_height
    d.qpos[3] = 1.0
    mujoco.mj_forward(model, d)
    return d


def turned(model: mujoco.MjModel, d: mujoco.MjData) -> mujoco.MjData:
    """``d`` turned by :data:`TURN` about the world's vertical axis and moved by
    :data:`SHIFT`: the free joint's position, orientation, linear velocity (world frame)
    and the warm start's linear part rotated; the angular velocity (body frame) and the
    joints as they were."""
    out = copy.copy(d)
    c, s = math.cos(TURN), math.sin(TURN)
    rot = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
    out.qpos[:3] = rot @ d.qpos[:3] + SHIFT
    q = np.zeros(4)
    mujoco.mju_mulQuat(q, np.array([math.cos(TURN / 2), 0.0, 0.0, math.sin(TURN / 2)]), d.qpos[3:7])
    out.qpos[3:7] = q
    out.qvel[:3] = rot @ d.qvel[:3]
    mujoco.mj_forward(model, out)
    out.qacc_warmstart[:] = d.qacc_warmstart
    out.qacc_warmstart[:3] = rot @ d.qacc_warmstart[:3]
    return out


def nudged(model: mujoco.MjModel, d: mujoco.MjData) -> mujoco.MjData:
    """``d`` with the left front femur :data:`NUDGE` rad further (not turned)."""
    out = copy.copy(d)
    out.qpos[8] += NUDGE
    mujoco.mj_forward(model, out)
    out.qacc_warmstart[:] = d.qacc_warmstart
    return out


def control_step(model: mujoco.MjModel, d: mujoco.MjData, ctrl: np.ndarray, substeps: int) -> None:
    """One control step as the env's C engine takes it: ``substeps`` ``mj_step`` calls,
    then the state rounded to float32, as the env's state holds it."""
    d.ctrl[:] = ctrl
    for _ in range(substeps):
        mujoco.mj_step(model, d)
    for field in (d.qpos, d.qvel, d.act, d.qacc_warmstart):
        field[:] = field.astype(np.float32)


def compare(
    model: mujoco.MjModel, env: Any, obs_fn: Any, policy: Any, warm: int, copy_of: Any
) -> dict[str, Any]:
    """One scenario: A from the start pose, ``warm`` control steps of ``policy``, then A and
    B = ``copy_of(model, A)`` driven on for :data:`STEPS` control steps."""
    n, dt = env.sim.substeps, env.control_dt
    a = start(model, env)
    for k in range(warm):
        control_step(model, a, np.asarray(env.robot.command(policy(k * dt))), n)
    b = copy_of(model, a)
    obs, joints, iters = [], [], []
    for k in range(warm, warm + STEPS):
        ctrl = np.asarray(env.robot.command(policy(k * dt)))
        control_step(model, a, ctrl, n)
        control_step(model, b, ctrl, n)
        iters.append(int(a.solver_niter[0]))
        oa, ob = (np.asarray(obs_fn(_State(x.qpos.copy(), x.qvel.copy()))) for x in (a, b))
        obs.append(np.abs(oa - ob).max())
        joints.append(np.abs(a.qpos[7:] - b.qpos[7:]).max())
    at_0p6 = round(0.6 / dt) - 1
    return {
        "obs_1": float(obs[0]),
        "obs_5": float(max(obs[:5])),
        "joint_0p6s": float(joints[at_0p6]),
        "joint_2s": float(max(joints)),
        "walked_m": float(np.linalg.norm(a.qpos[:2])),
        "iters": iters,
    }


def step_seconds(model: mujoco.MjModel, env: Any, seconds: float = 20.0) -> float:
    """CPU seconds of this thread per ``mj_step`` over ``seconds`` of the tripod gait from
    the start pose (ctrl set every control step, outside the timing). Thread time, not wall
    time: the machine is shared, and a preempted step is not charged."""
    n, dt = env.sim.substeps, env.control_dt
    ctrls = [np.asarray(env.robot.command(tripod(k * dt))) for k in range(round(seconds / dt))]
    d = start(model, env)
    elapsed = 0.0
    for ctrl in ctrls:
        d.ctrl[:] = ctrl
        t0 = time.thread_time()
        for _ in range(n):
            mujoco.mj_step(model, d)
        elapsed += time.thread_time() - t0
    return elapsed / (len(ctrls) * n)


def loop_vs_env(steps: int = 20) -> float:
    """The largest |qpos| difference, one control step of the tripod gait from the env's
    own state at a time over ``steps``, between :func:`control_step` and the env's C engine
    step (``env.sim.step``), both with the pyramidal cone and a converged solver (50 CG
    iterations, 10 line-search steps: the env's own cone, and a solve whose result does not
    hang on rounding)."""
    env = jaxenvs.make(ENV_ID, physics="c", solver_iterations=50, ls_iterations=10)
    model = configured(
        env.sim.physics_mj_model, Setting("CG", "pyramidal", 50, 10), env.default_params.model
    )
    d = start(model, env)
    data = env.sim.init_data(qpos=jnp.asarray(d.qpos, jnp.float32), qvel=jnp.zeros(model.nv))
    fields = env.sim.model_with(env.default_params.model)
    worst = 0.0
    for k in range(steps):
        for name in ("qpos", "qvel", "qacc_warmstart"):
            getattr(d, name)[:] = np.asarray(getattr(data, name), np.float64)
        ctrl = env.robot.command(jnp.asarray(tripod(k * env.control_dt), jnp.float32))
        data = env.sim.step(fields, data, ctrl)
        control_step(model, d, np.asarray(ctrl, np.float64), env.sim.substeps)
        worst = max(worst, float(np.abs(np.asarray(data.qpos, np.float64) - d.qpos).max()))
    return worst


#: the tiles (top level) the robot stands on in :func:`stand_on_terrain`
STAND_TILES = ("flat", "rough_slope", "obstacles")


def terrain_model(env: Any) -> tuple[mujoco.MjModel, Terrain]:
    """The robot on the default generated terrain (jaxenvs.scenes.terrain): the same six
    foot pairs with the heightfield in place of the plane, the env's options."""
    terrain = generate()
    scene = Scene(robot=env.robot.xml, ground=terrain, contacts=tuple(f"{g}_foot" for g in LEGS))
    m = scene.spec().compile()
    m.opt.timestep = env.sim.physics_mj_model.opt.timestep
    m.opt.disableflags = env.sim.physics_mj_model.opt.disableflags
    return m, terrain


def stand_on_terrain(model: mujoco.MjModel, terrain: Terrain, env: Any) -> dict[str, float]:
    """The robot dropped from the start pose on each of :data:`STAND_TILES`' spawn points at
    the top level, servos at the stance: the range of the torso's height over seconds 1 to 3
    (on the plane, under 0.1 mm) and the mean number of contacts."""
    ranges, contacts = [], []
    for name in STAND_TILES:
        x, y, z = terrain.origins[terrain.levels - 1, terrain.types.index(name)]
        d = mujoco.MjData(model)
        d.qpos[:3] = (x, y, z + env.config.init_height)
        d.qpos[3] = 1.0
        heights = []
        for k in range(round(3.0 / model.opt.timestep)):
            mujoco.mj_step(model, d)
            if k * model.opt.timestep >= 1.0:
                heights.append(d.qpos[2])
                contacts.append(d.ncon)
        ranges.append(max(heights) - min(heights))
    return {
        "terrain_stand_range_m": float(max(ranges)),
        "terrain_contacts": float(np.mean(contacts)),
    }


def measure(
    model: mujoco.MjModel, env: Any, obs_fn: Any, scenarios: dict[str, Any]
) -> dict[str, Any]:
    """One setting's heading dependence (module docstring)."""
    per = {k: compare(model, env, obs_fn, pol, w, turned) for k, (pol, w) in scenarios.items()}
    floor = [compare(model, env, obs_fn, pol, w, nudged)["obs_5"] for pol, w in scenarios.values()]
    row: dict[str, Any] = {}
    for key in ("obs_1", "obs_5", "joint_0p6s", "joint_2s"):
        row[key] = max(p[key] for p in per.values())
        row[f"{key}_by_scenario"] = [p[key] for p in per.values()]
    row["isotropic"] = row["obs_5"] <= TARGET
    row["nudge_obs_5"] = max(floor)
    iters = [i for p in per.values() for i in p["iters"]]
    row["solver_iters_mean"] = float(np.mean(iters))
    row["solver_iters_max"] = int(max(iters))
    row["walked_m"] = per["start"]["walked_m"]
    return row


def main() -> None:
    parser = argparse.ArgumentParser(description=(__doc__ or "").split("\n\n")[0])
    parser.add_argument("--json", help=results_io.HELP)
    parser.add_argument("--rounds", type=int, default=5, help="timing rounds over all settings")
    args = parser.parse_args()
    env = jaxenvs.make(ENV_ID, physics="c")
    base = hexapod_model(env)
    models = [configured(base, s, env.default_params.model) for s in SETTINGS]
    task = (jnp.zeros(3), jnp.zeros((env.action_history, 18)))
    obs_fn = jax.jit(lambda s: env.observation(env.robot.sense(s), task))
    scenarios = {"start": (tripod, 0), "gait": (tripod, WARM_STEPS)}
    scenarios.update({f"random{i}": (smooth_random(i), WARM_STEPS) for i in range(3)})
    rows = []
    ground, terrain = terrain_model(env)
    for setting, model in zip(SETTINGS, models, strict=True):
        on_terrain = stand_on_terrain(configured(ground, setting, {}), terrain, env)
        rows.append(setting._asdict() | measure(model, env, obs_fn, scenarios) | on_terrain)
        print({k: v for k, v in rows[-1].items() if not k.endswith("by_scenario")}, flush=True)
    best = [math.inf] * len(SETTINGS)
    for _ in range(args.rounds):  # interleaved: a busy moment slows every setting alike
        for i, model in enumerate(models):
            best[i] = min(best[i], step_seconds(model, env))
    for row, seconds in zip(rows, best, strict=True):
        row["steps_per_cpu_s"] = 1.0 / seconds
        row["cost_vs_today"] = seconds / best[0]
        name = f"{row['solver']} {row['cone']} {row['iterations']}/{row['ls_iterations']}"
        print(f"{name}: {1 / seconds:.0f} steps/s, {seconds / best[0]:.2f}x the first")
    extra = {
        "scenarios": list(scenarios),
        "turn_rad": TURN,
        "shift_m": SHIFT.tolist(),
        "nudge_rad": NUDGE,
        "target_obs_5": TARGET,
        "loop_vs_env_qpos": loop_vs_env(),
        "load_average": os.getloadavg(),
    }
    print("loop vs env:", extra["loop_vs_env_qpos"])
    if args.json:
        title = "Heading dependence of the hexapod's contact and its step cost, MuJoCo C, 2 cores"
        where = f"the shared {os.cpu_count()}-core development machine"
        rec = results_io.record(args.json, title, rows, description=where, engine="c", extra=extra)
        results_io.write(args.json, rec)


if __name__ == "__main__":
    main()
