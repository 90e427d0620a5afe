"""benchmarks/peers.py, the peers' harness: missing peers reported, ratios to our best."""

from __future__ import annotations

import sys
from pathlib import Path

import pytest

from jaxenvs import bench

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
import peers  # noqa: E402


def test_missing_peer_is_reported_skipped(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setitem(sys.modules, "envpool", None)  # import envpool -> ImportError
    monkeypatch.setitem(sys.modules, "gymnax", None)
    found = peers.peer_runners("CartPole-v0", num_envs=2, gymnax_envs=2, sync_envs=2)
    by_name = {p.name: p for p in found}
    assert set(by_name) == {
        "gymnasium",
        "gymnasium SyncVectorEnv",
        "envpool",
        "mujoco.rollout",
        "gymnax",
    }
    for name in ("envpool", "gymnax"):
        assert isinstance(by_name[name], peers.Skipped)
        assert by_name[name].reason.startswith("not installed")
        assert by_name[name].as_dict()["skipped"] is True
    rollout = by_name["mujoco.rollout"]
    assert isinstance(rollout, bench.Runner)
    assert rollout.unit() == 2 * 200  # 2 envs x 200 control steps at 1 substep


def test_ratios_compare_best_batch_to_each_peer() -> None:
    results = [
        {"name": "jaxenvs", "task": "T", "variant": "full", "num_envs": 4, "env_steps_per_s": 10},
        {"name": "jaxenvs", "task": "T", "variant": "full", "num_envs": 8, "env_steps_per_s": 40},
        {
            "name": "jaxenvs",
            "task": "T",
            "variant": "functional",
            "num_envs": 8,
            "env_steps_per_s": 99,
        },
        {"name": "envpool", "task": "T", "variant": "X", "num_envs": 2, "env_steps_per_s": 20},
        {"name": "gymnax", "task": "T", "variant": "Y", "skipped": True, "reason": "r"},
    ]
    (row,) = peers.ratios(results)
    assert row["our_envs"] == 8 and row["ratio"] == pytest.approx(2.0)
    assert row["physics"] == "mjx"  # results without an engine are MJX's
    c_result = {**results[1], "physics": "c", "env_steps_per_s": 60}
    rows = {r["physics"]: r for r in peers.ratios([*results, c_result])}
    assert rows["c"]["ratio"] == pytest.approx(3.0) and rows["mjx"]["ratio"] == pytest.approx(2.0)
