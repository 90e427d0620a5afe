"""The tutorial (docs/custom_task.md) as tests: a user's own task package, registered on
import, goes through the battery, ``make``, Gymnasium, ``jaxenvs train`` and
``jaxenvs bench`` with no further code. Also: the battery names what a broken task got
wrong, and installed packages are found through the ``jaxenvs.envs`` entry points.

The task defaults to MJX (it declares no faster CPU engine); the tests of its logic step it
with the C engine (``physics`` is one more config override, tests/engines.py), the bench
runs it on MJX, and the full tier runs the battery on MJX as well.
"""

from __future__ import annotations

import importlib.metadata
import json
import os
import re
import subprocess
import sys
from pathlib import Path

import gymnasium
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from engines import TASK_LOGIC

ROOT = Path(__file__).resolve().parents[2]
EXAMPLE = ROOT / "examples" / "pendulum"
sys.path.insert(0, str(EXAMPLE))

import my_pendulum  # noqa: E402  (registers MyPendulum-v0)
from my_pendulum.task import Pendulum, PendulumConfig  # noqa: E402

import jaxenvs  # noqa: E402
from jaxenvs import registry  # noqa: E402
from jaxenvs.cli import main  # noqa: E402
from jaxenvs.core import NoExtras  # noqa: E402
from jaxenvs.testing import TaskCheckError, check_task  # noqa: E402

ID = "MyPendulum-v0"
#: what a command-line user types when the package is not installed (module:Id)
CLI_ID = "my_pendulum:MyPendulum-v0"


def test_registered_on_import() -> None:
    assert ID in jaxenvs.list_envs()
    assert jaxenvs.spec(ID).factory is my_pendulum.Pendulum
    assert jaxenvs.spec(CLI_ID) is jaxenvs.spec(ID)


@pytest.mark.parametrize("physics", [TASK_LOGIC, pytest.param("mjx", marks=pytest.mark.full)])
def test_passes_the_battery(physics: str) -> None:
    # 50-step episodes so that the 120-step rollout sees auto-resets
    env = jaxenvs.make(ID, episode_length=50, physics=physics)
    check_task(env, num_envs=4, rollout_steps=120)


@pytest.mark.full
def test_make_batched_and_overrides() -> None:
    benv = jaxenvs.make(CLI_ID, num_envs=4, max_torque=3.0, physics=TASK_LOGIC)
    assert isinstance(benv, jaxenvs.BatchedEnv) and benv.config.max_torque == 3.0
    state = jax.jit(benv.reset)(jax.random.key(0))
    state = jax.jit(benv.step)(state, jnp.ones((4, 1)))
    assert state.obs.shape == (4, 3) and state.reward.shape == (4,)
    # the observation is (cos, sin, velocity) of the hinge
    np.testing.assert_allclose(
        np.asarray(state.obs[:, 0] ** 2 + state.obs[:, 1] ** 2), np.ones(4), atol=1e-5
    )
    with pytest.raises(jaxenvs.ConfigError, match="max_torque"):
        jaxenvs.make(ID, max_torque=-1.0)


@pytest.mark.full
def test_gymnasium_make() -> None:
    env = gymnasium.make(f"jaxenvs/{ID}", physics=TASK_LOGIC)
    assert env.spec is not None and env.spec.max_episode_steps == 200
    assert env.unwrapped.jax_env.physics == TASK_LOGIC
    obs, _ = env.reset(seed=0)
    assert obs.shape == (3,) and env.observation_space.contains(obs)
    total = 0.0
    for _ in range(5):
        obs, reward, terminated, truncated, info = env.step(env.action_space.sample())
        total += reward
        assert not terminated and not truncated and "upright" in info
    assert np.isfinite(total) and total < 0  # the reward is a cost, 0 at best
    env.close()


@pytest.fixture(scope="module")
def run_dir(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A tiny PPO run through the command line, as the tutorial shows it."""
    out = tmp_path_factory.mktemp("runs") / "pendulum-ppo"
    argv = [
        "train", CLI_ID, "--algo", "ppo", "--config", str(EXAMPLE / "ppo_MyPendulum-v0.yaml"),
        "--num-envs", "4", "--total-steps", "800", "--eval-episodes", "1",
        "--no-video", "--no-compile-cache", "--quiet", "--out", str(out),
        "--physics", TASK_LOGIC,
    ]  # fmt: skip
    assert main(argv) == 0
    return out


@pytest.mark.full
def test_train_from_the_command_line(run_dir: Path) -> None:
    summary = json.loads((run_dir / "summary.json").read_text())
    assert summary["env_steps"] >= 800 and np.isfinite(summary["eval_mean_return"])
    assert (run_dir / "config.yaml").read_text().count(CLI_ID) == 1
    assert summary["physics"] == TASK_LOGIC


@pytest.mark.full
def test_trained_policy_plays(run_dir: Path) -> None:
    from jaxenvs.run.runner import load_policy

    env_id, env, act_fn = load_policy(run_dir)
    assert env_id == CLI_ID and isinstance(env, Pendulum)
    action = jax.jit(act_fn)(jnp.zeros(3), jax.random.key(0))
    assert action.shape == (1,) and bool(jnp.all(jnp.abs(action) <= 1))


@pytest.mark.full  # needs the tutorial's trained run (run_dir)
def test_view_policy_must_match_the_id(
    run_dir: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    monkeypatch.setenv("DISPLAY", ":99999")  # checked before any window opens
    assert main(["view", "CartPole-v0", "--policy", str(run_dir)]) == 2
    assert f"is a run of {CLI_ID}, not CartPole-v0" in capsys.readouterr().err


@pytest.mark.full
def test_render_a_video_of_the_policy(run_dir: Path, tmp_path: Path) -> None:
    out = tmp_path / "pendulum.gif"
    argv = [
        "render", CLI_ID, "--policy", str(run_dir), "--out", str(out),
        "--steps", "8", "--width", "64", "--height", "48",
    ]  # fmt: skip
    assert main(argv) == 0
    assert out.stat().st_size > 0


def test_tutorial_listings_are_the_example_files() -> None:
    doc = (ROOT / "docs" / "custom_task.md").read_text()
    listings = re.findall(r"<!-- file: (\S+) -->\n```\w*\n(.*?)```", doc, re.S)
    assert {path for path, _ in listings} >= {
        "examples/pendulum/my_pendulum/task.py",
        "examples/pendulum/my_pendulum/__init__.py",
        "examples/pendulum/my_pendulum/pendulum.xml",
    }
    for path, text in listings:
        assert text == (ROOT / path).read_text(), f"docs/custom_task.md shows an old {path}"


@pytest.mark.full
def test_bench_from_the_command_line(capsys: pytest.CaptureFixture[str]) -> None:
    argv = [
        "bench", "--tasks", CLI_ID, "--batches", "2", "--modes", "full",
        "--steps", "5", "--repeats", "1", "--target-s", "0.01", "--physics", TASK_LOGIC,
    ]  # fmt: skip
    assert main(argv) == 0
    out = capsys.readouterr().out
    assert CLI_ID in out and "steps/s" in out


# ------------------------------------------------------------------ broken toy tasks
class IgnoresKey(Pendulum):
    """Bug: every reset starts from the same state."""

    def _init(self, key, params):  # type: ignore[no-untyped-def]
        return super()._init(jax.random.key(0), params)


class Retraces(Pendulum):
    """Bug: the step turns an int32 counter in ``extras`` into a float (new signature)."""

    def _init(self, key, params):  # type: ignore[no-untyped-def]
        data, _ = super()._init(key, params)
        return data, jnp.zeros((), jnp.int32)

    def _act(self, key, data, extras, action, params):  # type: ignore[no-untyped-def]
        data, _ = super()._act(key, data, NoExtras(), action, params)
        return data, extras + 0.5


@pytest.mark.full
def test_example_with_observation_noise_passes_the_battery() -> None:
    check_task(Pendulum(PendulumConfig(physics=TASK_LOGIC, obs_noise=0.1)), rollout_steps=50)


@pytest.mark.full
def test_battery_names_a_reset_that_ignores_its_key() -> None:
    with pytest.raises(TaskCheckError, match=r"^\[determinism\] reset with different keys"):
        check_task(IgnoresKey(PendulumConfig(physics=TASK_LOGIC)))


@pytest.mark.full
def test_battery_names_a_step_that_retraces() -> None:
    with pytest.raises(TaskCheckError, match=r"^\[single_trace\] reset traced 1x and step [2-9]x"):
        check_task(Retraces(PendulumConfig(physics=TASK_LOGIC)))


# ------------------------------------------------------------ installed packages
def _fake_entry_points(monkeypatch: pytest.MonkeyPatch, *entries: tuple[str, str]) -> None:
    eps = [importlib.metadata.EntryPoint(n, v, registry.ENTRY_POINT_GROUP) for n, v in entries]

    def entry_points(group: str) -> list[importlib.metadata.EntryPoint]:
        return eps if group == registry.ENTRY_POINT_GROUP else []

    monkeypatch.setattr(importlib.metadata, "entry_points", entry_points)
    monkeypatch.setattr(registry, "_plugins_loaded", False)


def test_installed_package_found_through_entry_point(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    (tmp_path / "toy_plugin.py").write_text(
        "import jaxenvs\n"
        "from my_pendulum.task import Pendulum, PendulumConfig\n"
        "jaxenvs.register('ToyPlugin-v0', Pendulum, PendulumConfig(max_torque=1.0))\n"
    )
    monkeypatch.syspath_prepend(str(tmp_path))
    _fake_entry_points(monkeypatch, ("toy", "toy_plugin"), ("broken", "no_such_module_xyz"))
    try:
        with pytest.warns(UserWarning, match="plugin 'broken'.*failed to load"):
            assert jaxenvs.spec("ToyPlugin-v0").config.max_torque == 1.0
        assert "ToyPlugin-v0" in jaxenvs.list_envs()
    finally:
        registry._REGISTRY.pop("ToyPlugin-v0", None)
        sys.modules.pop("toy_plugin", None)


@pytest.mark.full
def test_installed_package_listed_by_the_command_line(tmp_path: Path) -> None:
    """A real installed distribution (a dist-info with an entry point) on sys.path."""
    (tmp_path / "toy_plugin.py").write_text(
        "import jaxenvs\n"
        "from my_pendulum.task import Pendulum, PendulumConfig\n"
        "jaxenvs.register('ToyPlugin-v0', Pendulum, PendulumConfig())\n"
    )
    info = tmp_path / "toy_plugin-0.1.dist-info"
    info.mkdir()
    (info / "METADATA").write_text("Metadata-Version: 2.1\nName: toy-plugin\nVersion: 0.1\n")
    (info / "entry_points.txt").write_text(f"[{registry.ENTRY_POINT_GROUP}]\ntoy = toy_plugin\n")
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(tmp_path), str(EXAMPLE)]))
    proc = subprocess.run(
        [sys.executable, "-W", "error::UserWarning", "-m", "jaxenvs", "list", "--ids"],
        env=env,
        capture_output=True,
        text=True,
        timeout=300,
        check=False,
    )
    assert proc.returncode == 0, proc.stderr[-2000:]
    assert proc.stdout.split()[-1] == "ToyPlugin-v0"


def test_unknown_module_prefix_is_a_user_error(capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(ValueError, match="cannot import 'no_such_pkg'"):
        jaxenvs.make("no_such_pkg:Thing-v0")
    assert main(["bench", "--tasks", "no_such_pkg:Thing-v0"]) == 2
    assert "cannot import" in capsys.readouterr().err
