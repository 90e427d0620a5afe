"""HexapodJoystickRough-v0: the terrain as the ground, the level curriculum's rule, the
spawn on the env's tile, heights and falls above the ground, a blind observation, the
level in the run's figures, the viewer's camera and the simulated robot's tile. (The
public battery runs on it in tests/tasks/test_battery.py: MuJoCo C in the default tier,
MJX in the full tier.)

Most tests use a small terrain (4 levels of flat ground, stairs up and stairs down): at
its top level the stairs' platform is 0.56 m below (a pit) or above (a summit) the
tiles' edges."""

from __future__ import annotations

import contextlib
import dataclasses
from pathlib import Path
from typing import Any

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
import pytest

import jaxenvs
from jaxenvs.config import ConfigError
from jaxenvs.core import BatchedEnv
from jaxenvs.run import results
from jaxenvs.scenes import MAX_CONTACTS
from jaxenvs.tasks.hexapod.rough import (
    SCAN_KEYS,
    HexapodJoystickRough,
    JoystickRoughConfig,
    RoughCarry,
)
from jaxenvs.tasks.hexapod.walk_rough import WalkRoughConfig

ID = "HexapodJoystickRough-v0"
SMALL = {"levels": 4, "terrain_types": ("flat", "stairs_up", "stairs_down")}
FLAT, PIT, SUMMIT = 0, 1, 2  # the small terrain's columns
TOP = 3


@pytest.fixture(scope="module")
def env() -> HexapodJoystickRough:
    made = jaxenvs.make(ID, physics="c", **SMALL)
    assert isinstance(made, HexapodJoystickRough)
    return made


_PROGRAMS: dict[tuple[int, str], Any] = {}


def _jit(env: HexapodJoystickRough, name: str) -> Any:
    """``env``'s programs, jitted once per module (an eager call compiles each of its
    operations on its own)."""
    if (id(env), name) not in _PROGRAMS:
        fn = {
            "starts": BatchedEnv(env, 1, devices=1).fresh_starts,
            "next": jax.vmap(env.next_carry),
            "carry": jax.vmap(env.initial_carry),
        }[name]
        _PROGRAMS[id(env), name] = jax.jit(fn)
    return _PROGRAMS[id(env), name]


def starts(env: HexapodJoystickRough, levels: Any, columns: Any, seed: int = 0) -> Any:
    """Fresh starts (a batch) of envs with these levels and columns."""
    levels, columns = np.broadcast_arrays(np.asarray(levels), np.asarray(columns))
    carry = RoughCarry(level=jnp.asarray(levels, jnp.int32), column=jnp.asarray(columns, jnp.int32))
    keys = jax.random.split(jax.random.key(seed), levels.size)
    return _jit(env, "starts")(keys, None, carry)


def test_the_terrain_is_the_ground_with_the_rough_contact_setting(env) -> None:
    """The feet are paired with the terrain's heightfield; the family's contact (elliptic;
    under C Newton 4 / 20) with the rough task's own CG for MJX on a CPU (30 / 10, where
    the flat joystick's is 6 / 3)."""
    m = env.sim.mj_model
    assert m.nhfield == 1 and m.npair == 6
    hfield = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_GEOM, "terrain")
    assert set(m.pair_geom1) == {hfield}
    newton = (mujoco.mjtSolver.mjSOL_NEWTON, 4, 20)
    for model in (m, env.sim.physics_mj_model):
        assert model.opt.cone == mujoco.mjtCone.mjCONE_ELLIPTIC
        assert (model.opt.solver, model.opt.iterations, model.opt.ls_iterations) == newton
    mjx_cpu = HexapodJoystickRough(dataclasses.replace(env.config, physics="mjx")).sim.mj_model
    cg = (mujoco.mjtSolver.mjSOL_CG, 30, 10)
    assert (mjx_cpu.opt.solver, mjx_cpu.opt.iterations, mjx_cpu.opt.ls_iterations) == cg
    flat = jaxenvs.make("HexapodJoystick-v0", physics="mjx").sim.mj_model
    assert flat.opt.cone == mujoco.mjtCone.mjCONE_ELLIPTIC
    assert (flat.opt.solver, flat.opt.iterations, flat.opt.ls_iterations) == (cg[0], 6, 3)
    assert flat.nhfield == 0
    pyramid = HexapodJoystickRough(dataclasses.replace(env.config, cone="pyramidal"))
    assert pyramid.sim.mj_model.opt.cone == mujoco.mjtCone.mjCONE_PYRAMIDAL


def test_no_episode_walks_off_the_field(env) -> None:
    """From every tile's centre, an episode at the fastest command (both speeds at their
    range's end, in a straight line, for the whole episode) ends with the feet (within
    0.3 m of the body) at least a metre inside the heightfield."""
    c, t = env.config, env.terrain
    lo, hi = env.command_range
    reach = float(np.hypot(max(abs(lo[0]), hi[0]), max(abs(lo[1]), hi[1])))
    reach *= c.episode_length * env.control_dt
    rows, cols = t.heights.shape
    x0, y0 = t.corner[0], t.corner[1]
    x1, y1 = x0 + (cols - 1) * t.config.spacing, y0 + (rows - 1) * t.config.spacing
    centres = t.origins[..., :2].reshape(-1, 2)
    margin = np.minimum.reduce(
        [centres[:, 0] - x0, x1 - centres[:, 0], centres[:, 1] - y0, y1 - centres[:, 1]]
    )
    assert reach > 9.0 and margin.min() > reach + 0.3 + 1.0


def test_mjx_keeps_the_six_deepest_contacts(env) -> None:
    """The rough joystick's MJX model carries its contact budget (6 of the feet's 24 slots
    on the heightfield: ``max_contacts``), the terrain tasks' field whose default (the
    walker's) is 8; the flat joystick's carries none, and 0 lifts it."""
    numeric = mujoco.mjtObj.mjOBJ_NUMERIC
    rough = HexapodJoystickRough(dataclasses.replace(env.config, physics="mjx")).sim
    budget = mujoco.mj_name2id(rough.physics_mj_model, numeric, MAX_CONTACTS)
    assert budget >= 0 and rough.physics_mj_model.numeric_data[budget] == 6
    assert WalkRoughConfig().max_contacts == 8
    flat = jaxenvs.make("HexapodJoystick-v0", physics="mjx").sim.physics_mj_model
    assert mujoco.mj_name2id(flat, numeric, MAX_CONTACTS) == -1
    free = HexapodJoystickRough(dataclasses.replace(env.config, max_contacts=0)).sim
    assert mujoco.mj_name2id(free.physics_mj_model, numeric, MAX_CONTACTS) == -1


def test_first_levels_and_columns(env) -> None:
    keys = jax.random.split(jax.random.key(1), 400)
    carry = _jit(env, "carry")(keys)
    assert set(np.asarray(carry.level).tolist()) == {0, 1, 2}  # max_init_level 2
    assert set(np.asarray(carry.column).tolist()) == {FLAT, PIT, SUMMIT}
    only = HexapodJoystickRough(
        dataclasses.replace(
            env.config, min_init_level=3, max_init_level=3, spawn_types=("stairs_up",)
        )
    )
    carry = jax.jit(jax.vmap(only.initial_carry))(keys[:16])
    assert np.all(np.asarray(carry.level) == 3) and np.all(np.asarray(carry.column) == PIT)


#: (level, walked m, commanded m, steps of the episode, the next level): the rule with
#: the defaults (3 m tiles: promotion past 1.5 m; demotion below half the commanded
#: distance over a whole 400-step episode)
RULE_CASES = [
    (1, 1.6, 1.0, 400, 2),  # past half a tile: promoted
    (1, 1.6, 10.0, 400, 2),  # promotion wins over demotion
    (1, 0.2, 2.0, 400, 0),  # under half of the commanded 2 m: demoted
    (1, 1.2, 2.0, 400, 1),  # over half of it: stays
    (0, 0.0, 2.0, 400, 0),  # no level below 0
    (1, 0.3, 0.2, 400, 1),  # a short command followed over the whole episode: stays
    (1, 0.3, 0.2, 40, 0),  # the same by a fall after 2 s: 2 m over a whole episode
    (2, 0.0, 0.0, 400, 2),  # standing still when told to: stays
]


def _finals(env: HexapodJoystickRough, cases: list[tuple], seed: int = 2) -> Any:
    """Synthetic finished episodes: each case's level, the body ``walked`` m from its
    spawn along a random direction, ``commanded`` m of commands, ``steps`` steps."""
    n = len(cases)
    level, walked, commanded, steps = (np.asarray(x) for x in list(zip(*cases, strict=True))[:4])
    final = starts(env, level, np.arange(n) % 3, seed)
    angle = np.random.default_rng(seed).uniform(-np.pi, np.pi, n)
    way = np.stack([np.cos(angle), np.sin(angle)], 1)
    spawn = np.asarray(final.extras.spawn)
    qpos = np.asarray(final.data.qpos).copy()
    qpos[:, :2] = spawn + walked[:, None] * way
    extras = final.extras.replace(commanded=jnp.asarray(commanded[:, None] * way, jnp.float32))
    return final.replace(
        data=final.data.replace(qpos=jnp.asarray(qpos)),
        extras=extras,
        time=jnp.asarray(steps, jnp.int32),
    )


def test_levels_move_by_the_rule(env) -> None:
    final = _finals(env, RULE_CASES)
    nxt = _jit(env, "next")(final)
    want = [case[-1] for case in RULE_CASES]
    np.testing.assert_array_equal(np.asarray(nxt.level), want)
    np.testing.assert_array_equal(np.asarray(nxt.column), np.asarray(final.carry.column))
    frozen = HexapodJoystickRough(dataclasses.replace(env.config, curriculum=False))
    kept = jax.jit(jax.vmap(frozen.next_carry))(final)
    np.testing.assert_array_equal(np.asarray(kept.level), [case[0] for case in RULE_CASES])


def test_past_the_top_level_an_env_goes_anywhere(env) -> None:
    final = _finals(env, [(TOP, 1.6, 1.0, 400, None)] * 64, seed=3)
    final = final.replace(key=jax.random.split(jax.random.key(4), 64))
    level = np.asarray(_jit(env, "next")(final).level)
    assert level.min() >= 0 and level.max() < env.config.levels
    assert len(set(level.tolist())) >= 3  # drawn: not one fixed level


def test_the_spawn_is_on_its_tile_at_its_ground_height(env) -> None:
    """Every tile's envs start ``init_height`` above its origin, the flat platform at its
    centre (the pit's and the summit's 0.56 m below and above the edges)."""
    levels, columns = np.meshgrid(np.arange(4), np.arange(3), indexing="ij")
    s = starts(env, levels.ravel(), columns.ravel())
    qpos = np.asarray(s.data.qpos)
    ground = np.asarray(jax.jit(env.ground)(jnp.asarray(qpos[:, :2])))
    np.testing.assert_allclose(qpos[:, 2], ground + env.config.init_height, atol=1e-6)
    for i, (level, col) in enumerate(zip(levels.ravel(), columns.ravel(), strict=True)):
        x0, x1, y0, y1 = env.terrain.tile_bounds(level, col)
        assert abs(qpos[i, 0] - (x0 + x1) / 2) < 1e-4 and abs(qpos[i, 1] - (y0 + y1) / 2) < 1e-4
        assert env.tile_of(qpos[i, :2]) == (level, col)
    top = {c: ground[TOP * 3 + c] for c in (FLAT, PIT, SUMMIT)}
    assert (
        top[FLAT] == 0.0 and top[PIT] == pytest.approx(-0.56) and top[SUMMIT] == pytest.approx(0.56)
    )
    np.testing.assert_array_equal(np.asarray(s.extras.level), levels.ravel())
    np.testing.assert_allclose(np.asarray(s.extras.spawn), qpos[:, :2])


def test_falls_are_measured_above_the_ground(env) -> None:
    """In the pit (ground 0.56 m below z = 0) a standing robot is up, where the flat
    rule (above z = 0) would call it fallen; on the summit a body 3 cm above the ground
    has fallen, where the flat rule would call it up."""
    s = starts(env, [TOP, TOP], [PIT, SUMMIT])

    one = jax.tree.map(lambda x: x[0], s.data)

    @jax.jit
    def rules(qpos: jax.Array) -> jax.Array:
        """(this task's rule, the flat rule) of each pose."""

        def both(q: jax.Array) -> jax.Array:
            readings = env.robot.sense(one.replace(qpos=q))
            c = env.config  # the flat floor's rule: the body's height above z = 0
            flat = (env.robot.height(readings) < c.min_height) | (
                env.robot.upright(readings) < c.min_upright
            )
            return jnp.stack([env.fallen(readings), flat])

        return jax.vmap(both)(qpos)

    low = s.data.qpos.at[1, 2].set(0.56 + 0.03)  # on the summit, 3 cm above the ground
    np.testing.assert_array_equal(np.asarray(rules(s.data.qpos))[0], [False, True])  # the pit
    np.testing.assert_array_equal(np.asarray(rules(low))[1], [True, False])


def metrics(env: HexapodJoystickRough, s: Any) -> dict[str, np.ndarray]:
    """The task's metrics of each env's state ``s`` (the reward hook's, of a step that
    stayed there: no physics is compiled)."""
    if (id(env), "metrics") not in _PROGRAMS:

        def one(state: Any) -> dict[str, jax.Array]:
            zero = jnp.zeros(18)
            return env._reward(state.data, state.data, zero, state.extras, env.default_params)[1]

        _PROGRAMS[id(env), "metrics"] = jax.jit(jax.vmap(one))
    return {k: np.asarray(v) for k, v in _PROGRAMS[id(env), "metrics"](s).items()}


def test_level_and_height_scan_metrics(env) -> None:
    """``level`` is the episode's; on a flat platform every scan point reads the ground
    ``height`` below the torso; off the platform, the stairs show in the scan."""
    s = starts(env, [TOP, 2], [SUMMIT, FLAT])
    m = metrics(env, s)
    np.testing.assert_array_equal(m["level"], [TOP, 2])
    np.testing.assert_allclose(m["height"], env.config.init_height, atol=1e-6)
    scan = np.stack([m[k] for k in SCAN_KEYS], 1)
    np.testing.assert_allclose(scan, np.full(scan.shape, -env.config.init_height), atol=1e-6)
    # moved 0.4 m along x, facing +x, to the summit's edge: the scan's front steps down
    qpos = s.data.qpos.at[:, 0].add(0.4).at[:, 3:7].set(jnp.array([1.0, 0, 0, 0]))
    m = metrics(env, s.replace(data=s.data.replace(qpos=qpos)))
    grid = np.stack([m[k] for k in SCAN_KEYS], 1).reshape(2, 7, 7)  # (y, x): x fastest
    assert grid[0, :, -1].mean() < grid[0, :, 0].mean() - 0.05  # lower ahead
    np.testing.assert_allclose(grid[1], -env.config.init_height, atol=1e-6)  # flat ground


def test_the_low_body_penalty(env) -> None:
    """With ``low_body_weight`` the reward loses ``weight * (low_body_height - h)^2`` for a
    body ``h`` above the ground under ``low_body_height``, and nothing above it; the
    metrics are the same."""
    weighted = HexapodJoystickRough(
        dataclasses.replace(env.config, low_body_weight=400.0, low_body_height=0.09)
    )
    s = starts(env, [TOP, TOP], [SUMMIT, PIT])
    ground = np.asarray(s.data.qpos[:, 2]) - env.config.init_height
    qpos = s.data.qpos.at[:, 2].set(jnp.asarray(ground + np.array([0.07, 0.12])))
    s = s.replace(data=s.data.replace(qpos=qpos))

    def rewards(task: HexapodJoystickRough) -> tuple[np.ndarray, dict[str, Any]]:
        def one(state: Any) -> Any:
            return task._reward(
                state.data, state.data, jnp.zeros(18), state.extras, task.default_params
            )

        reward, m = jax.jit(jax.vmap(one))(s)
        return np.asarray(reward), m

    plain, m0 = rewards(env)
    less, m1 = rewards(weighted)
    np.testing.assert_allclose(np.asarray(m0["height"]), [0.07, 0.12], atol=1e-5)
    np.testing.assert_allclose(plain - less, [400.0 * 0.02**2, 0.0], atol=1e-4)
    assert all(np.array_equal(np.asarray(m0[k]), np.asarray(m1[k])) for k in m0)


def test_the_observation_is_blind(env) -> None:
    """The observation is the joystick's (63 entries): the same state on another tile,
    another level and another height gives the same observation."""
    assert env.observation_size == 63 and "scan_00" in env.metric_keys
    s = starts(env, [0, TOP], [FLAT, SUMMIT])
    one = jax.tree.map(lambda x: x[0], s)
    other = jax.tree.map(lambda x: x[1], s)
    moved = one.data.replace(qpos=one.data.qpos.at[:3].set(other.data.qpos[:3]))
    obs = [
        env.observation(env.robot.sense(d), env.task_state(d, one.extras))
        for d in (one.data, moved)
    ]
    np.testing.assert_array_equal(np.asarray(obs[0]), np.asarray(obs[1]))
    np.testing.assert_allclose(np.asarray(one.obs), np.asarray(obs[0]), atol=1e-6)  # no noise


def test_the_gait_prior_lifts_each_tripod_in_turn() -> None:
    """With ``gait_frequency`` (2.5 Hz: a cycle of 8 control steps) the env applies the
    policy's action plus a femur lift of ``gait_lift * max(0, sin)``, lf, rm, lr in the
    first half-cycle and rf, lm, rr in the second, none under a zero command; the
    observation (65 entries) holds the phase's sine and cosine before the command, the
    same from the env and from ``observation(readings, task_state)``; the applied action
    is what the observation's history holds."""
    env = jaxenvs.make(ID, physics="c", **SMALL, gait_frequency=2.5, gait_lift=0.4)
    assert isinstance(env, HexapodJoystickRough) and env.gait
    assert env.observation_size == 65
    command = jnp.asarray([0.2, 0.0, 0.0])
    lifts = np.stack([np.asarray(env.gait_offset(jnp.int32(k), command)) for k in range(8)])
    assert np.all(lifts[:, 0::3] == 0) and np.all(lifts[:, 2::3] == 0)  # femurs only
    femur = lifts[:, 1::3]  # (step, leg lf lm lr rf rm rr)
    np.testing.assert_allclose(femur[2], [0.4, 0, 0.4, 0, 0.4, 0], atol=1e-6)  # a quarter
    np.testing.assert_allclose(femur[6], [0, 0.4, 0, 0.4, 0, 0.4], atol=1e-6)
    assert np.all(femur[0] < 1e-6) and np.all(femur[4] < 1e-6)  # between the halves
    assert not np.any(np.asarray(env.gait_offset(jnp.int32(2), jnp.zeros(3))))
    s = jax.tree.map(lambda x: x[0], starts(env, [0], [FLAT]))
    s = env.with_command(s, command)
    step = jax.jit(env.step)
    action = jnp.full(18, 0.7)
    for k in range(3):
        task = env.task_state(s.data, s.extras)
        assert int(task[2]) == k
        angle = 2 * np.pi * 2.5 * 0.05 * k
        np.testing.assert_allclose(
            np.asarray(s.obs[-5:-3]), [np.sin(angle), np.cos(angle)], atol=1e-6
        )
        readings = env.robot.sense(s.data)
        np.testing.assert_allclose(
            np.asarray(env.observation(readings, task))[42:], np.asarray(s.obs)[42:], atol=1e-6
        )
        applied = env.prior_action(task, action)
        s = step(s, action, env.default_params)
        np.testing.assert_allclose(np.asarray(s.extras.actions[0]), np.asarray(applied))
    assert float(s.extras.actions[0][1]) == 1.0  # lf's femur at a quarter cycle: clipped


@pytest.mark.parametrize(
    "field, value",
    [
        ("cone", "conic"),
        ("gait_frequency", -1.0),
        ("gait_frequency", 10.0),  # half the 20 Hz control rate: the phase would alias
        ("gait_lift", -0.1),
        ("gait_lift", 2.5),
        ("low_body_weight", -1.0),
        ("low_body_height", -0.1),
        ("spawn_types", ("lava",)),
        ("max_init_level", 4),
        ("tile_size", 3.01),
        ("terrain_seed", -1),
        ("terrain_border", 0.01),
        ("terrain_types", ("flat", "moon")),
        ("terrain_spacing", 0.0),
        ("terrain_spacing", 0.5),  # the generator's 0.8 m platform no whole number of it
        ("hfield_contact", "prisms"),
    ],
)
def test_bad_config_is_named(field, value) -> None:
    config = JoystickRoughConfig(**{**SMALL, field: value})
    with pytest.raises(ConfigError, match=field):
        config.validate()


def test_a_tile_smaller_than_the_generators_platform_is_named() -> None:
    with pytest.raises(ConfigError, match="key 'tile_size'"):
        JoystickRoughConfig(**{**SMALL, "tile_size": 0.5}).validate()  # the platform: 0.8 m


def test_a_task_built_directly_names_its_bad_terrain_key() -> None:
    # the terrain is generated in __init__, before the env's own validate(): the config's
    # terrain fields are checked first, so the error names the task's key, not the
    # generator's (TerrainConfig.types)
    with pytest.raises(ConfigError, match="terrain_types"):
        HexapodJoystickRough(JoystickRoughConfig(**{**SMALL, "terrain_types": ("flat", "moon")}))


# ------------------------------------------------------------ the level in the run's figures
def test_the_run_reports_the_mean_level(tmp_path: Path) -> None:
    """:func:`results.task_level` averages the env state's ``level`` per seed; the bar
    shows it; the learning curve draws it where progress.csv has it, and a run without
    it draws as before."""
    from jaxenvs.core import State

    level = np.array([[0.0, 1.0, 2.0], [3.0, 3.0, 3.0]])
    fake = State(
        data=None, obs=None, reward=None, terminated=None, truncated=None,
        info={"level": jnp.asarray(level)}, extras=None, time=None, key=None,
    )  # fmt: skip
    np.testing.assert_allclose(results.task_level({"env_state": fake, "x": 1}), [1.0, 3.0])
    assert results.task_level({"x": jnp.zeros(2)}) is None
    metrics = {"episodes_in_chunk": 4, "mean_return": np.array([1.0]), "level": [1.0, 3.0]}
    assert results.progress_postfix(metrics, 1.0, 10)["level"] == "2.00"
    columns = results.metric_columns({"level": jax.ShapeDtypeStruct((2,), jnp.float32)})
    for run, with_level in (("rough", True), ("flat", False)):
        rows = [
            {"chunk": c, "seed": 0, "env_steps": 100 * (c + 1), "mean_return": c, "level": c / 2}
            for c in range(3)
        ]
        shown = columns if with_level else [c for c in columns if c != "level"]
        (tmp_path / run).mkdir()
        results.write_progress(tmp_path / run / "progress.csv", shown, rows)
    steps, curve = results.learning_curve(tmp_path / "rough", "level")
    np.testing.assert_allclose(curve[:, 0], [0.0, 0.5, 1.0])
    assert np.isnan(results.learning_curve(tmp_path / "flat", "level")[1]).all()
    for runs in (["rough"], ["flat"], ["rough", "flat"]):
        out = results.plot_curves([tmp_path / r for r in runs], tmp_path / "curve.png")
        assert out.stat().st_size > 1000


# ------------------------------------------------------------ the viewer and the robot
class _Handle:
    def __init__(self) -> None:
        self.cam = mujoco.MjvCamera()

    def lock(self) -> contextlib.nullcontext[None]:
        return contextlib.nullcontext()


def test_the_viewer_follows_the_robot_on_terrain(env) -> None:
    from jaxenvs.render import viewer

    handle = _Handle()
    viewer.follow_robot(handle, env.sim.mj_model)
    torso = mujoco.mj_name2id(env.sim.mj_model, mujoco.mjtObj.mjOBJ_BODY, "torso")
    assert handle.cam.type == mujoco.mjtCamera.mjCAMERA_TRACKING
    assert handle.cam.trackbodyid == torso
    flat = _Handle()
    viewer.follow_robot(flat, jaxenvs.make("HexapodJoystick-v0", physics="c").sim.mj_model)
    assert flat.cam.type == mujoco.mjtCamera.mjCAMERA_FREE


def test_robot_terrain_flag() -> None:
    from jaxenvs.cli.robot_cmd import terrain_overrides

    assert terrain_overrides(ID, None) == {}
    assert terrain_overrides(ID, "4") == {"min_init_level": 4, "max_init_level": 4}
    assert terrain_overrides(ID, "9:stairs_up")["spawn_types"] == ("stairs_up",)
    for bad, match in (("10", "0..9"), ("x", "level"), ("3:lava", "lava")):
        with pytest.raises(ConfigError, match=match):
            terrain_overrides(ID, bad)
    with pytest.raises(ConfigError, match="no terrain"):
        terrain_overrides("HexapodJoystick-v0", "1")


@pytest.mark.full  # the default terrain's C program (about 10 s on 2 cores)
def test_the_simulated_robot_starts_on_the_named_tile() -> None:
    from jaxenvs.cli.robot_cmd import terrain_overrides
    from jaxenvs.deploy import simrobot

    world = simrobot.build_world(ID, 0, terrain_overrides(ID, "6:stairs_down"))
    env = jaxenvs.make(ID, physics="c")
    assert isinstance(env, HexapodJoystickRough)
    column = env.terrain.types.index("stairs_down")
    origin = np.asarray(env.terrain.origins[6, column])
    assert world.model.nhfield == 1 and world.model.opt.cone == mujoco.mjtCone.mjCONE_ELLIPTIC
    for start in world.starts:
        np.testing.assert_allclose(start["qpos"][:2], origin[:2], atol=1e-5)
        assert start["qpos"][2] == pytest.approx(origin[2] + env.config.init_height, abs=1e-5)


@pytest.mark.full  # the C step's compile (about 10 s on 2 cores)
def test_standing_in_the_pit_and_on_the_summit(env) -> None:
    """10 control steps at the stance in the top level's pit and on its summit: up, and
    0.11-0.145 m above the ground (the flat rule would end the episode in the pit)."""
    s = starts(env, [TOP, TOP], [PIT, SUMMIT])
    step = jax.jit(jax.vmap(env.step))
    for _ in range(10):
        s = step(s, jnp.zeros((2, 18)))
    assert not np.asarray(s.terminated).any()
    height = np.asarray(s.info["height"])
    assert np.all((height > 0.11) & (height < 0.145)), height


# ------------------------------------------------------------ both engines
@pytest.mark.full  # MJX's heightfield collision compiles for about a minute on 2 cores
def test_mjx_and_c_agree() -> None:
    """In the air every metric (scan and level included) agrees step by step; on the
    ground, under the converged elliptic solve, the torso within 5 mm in height and 2 cm
    across, the joints within 0.05 rad over the first 10 steps of a sine gait."""
    from jaxenvs.testing import check_engine_parity

    check_engine_parity(ID, steps=3, init_height=0.3, **SMALL)
    t = np.arange(10)[:, None] * 0.05
    actions = jnp.asarray(0.2 * np.sin(np.pi * t + 0.7 * np.arange(18)[None, :]), jnp.float32)
    qpos = {}
    for physics in ("mjx", "c"):
        env = jaxenvs.make(ID, physics=physics, **SMALL)

        def roll(key: jax.Array, env: Any = env) -> jax.Array:
            def body(s: Any, a: jax.Array) -> tuple[Any, jax.Array]:
                s = env.step(s, a)
                return s, s.data.qpos

            return jax.lax.scan(body, env.reset(key), actions)[1]

        qpos[physics] = np.asarray(jax.jit(roll)(jax.random.key(3)))
    err = np.abs(qpos["mjx"] - qpos["c"])
    assert err[:, 2].max() < 0.005 and err[:, :2].max() < 0.02 and err[:, 7:].max() < 0.05, (
        err[:, 2].max(),
        err[:, :2].max(),
        err[:, 7:].max(),
    )
