"""``jaxenvs bench`` on a tiny batch: it runs, writes valid JSON, times the peers of a checkout
(the harness itself: benchmarks/tests/test_peers.py)."""

from __future__ import annotations

import json

import pytest

from jaxenvs.cli import bench_cmd, main


def _bench(path, *extra: str) -> dict:
    args = ["--tasks", "CartPole-v0", "--batches", "2", "--modes", "full", "--steps", "5"]
    args += ["--repeats", "2", "--target-s", "0.01", "--json", str(path), *extra]
    assert main(["bench", *args]) == 0
    return json.loads(path.read_text())


def _check_result(res: dict) -> None:
    assert res["name"] == "jaxenvs" and res["task"] == "CartPole-v0"
    assert res["num_envs"] == 2 and res["variant"] == "full"
    assert res["env_steps_per_s"] > 0
    assert res["min_env_steps_per_s"] <= res["env_steps_per_s"] <= res["max_env_steps_per_s"]
    assert res["first_call_s"] >= res["compile_s"] > 0


@pytest.mark.full
def test_bench_writes_valid_json_beside_the_peers(tmp_path) -> None:
    """One engine (C: no physics to compile); the full tier times both side by side. The
    peers installed with the package run in the same rounds, the others are listed skipped,
    and the ratio table compares ours with each peer that ran."""
    plot = tmp_path / "bench.png"
    peers_and_plot = ("--peers", "--peer-envs", "2", "--plot", str(plot))
    out = _bench(tmp_path / "bench.json", "--physics", "c", *peers_and_plot)
    ours = [r for r in out["results"] if r["name"] == "jaxenvs"]
    (res,) = ours
    _check_result(res)
    assert res["physics"] == "c" and res["threads"] >= 1
    assert out["machine"]["backend"] == "cpu"
    every_peer = {"gymnasium", "gymnasium SyncVectorEnv", "envpool", "mujoco.rollout", "gymnax"}
    assert {r["name"] for r in out["results"]} == {"jaxenvs", *every_peer}  # ran or skipped
    assert all(r["reason"] for r in out["results"] if r.get("skipped"))
    ran = [r for r in out["results"] if r["name"] != "jaxenvs" and not r.get("skipped")]
    assert {"gymnasium", "mujoco.rollout"} <= {r["name"] for r in ran}
    assert all(r["env_steps_per_s"] > 0 and r["task"] == "CartPole-v0" for r in ran)
    assert len(out["ratios"]) == len(ran)
    for q in out["ratios"]:
        assert q["ratio"] == pytest.approx(res["env_steps_per_s"] / q["peer_steps_per_s"])
    assert plot.read_bytes().startswith(b"\x89PNG")


@pytest.mark.full  # compiles the MJX rollout as well: the full tier
def test_bench_times_both_engines_by_default_on_a_cpu(tmp_path) -> None:
    out = _bench(tmp_path / "bench.json")
    results = {r["physics"]: r for r in out["results"]}
    assert sorted(results) == ["c", "mjx"] and len(out["results"]) == 2
    for res in results.values():
        _check_result(res)
    assert results["c"]["threads"] >= 1
    assert out["ratios"] == []


def test_peers_come_from_the_checkout(monkeypatch, capsys) -> None:
    """``--peers`` loads benchmarks/peers.py of the checkout; without one, a one-line error
    before anything compiles."""
    harness = bench_cmd.peer_harness()
    assert bench_cmd.PEERS_FILE.parent.name == "benchmarks"
    assert callable(harness.peer_runners) and callable(harness.ratios)
    monkeypatch.setattr(bench_cmd, "PEERS_FILE", bench_cmd.PEERS_FILE.with_name("absent.py"))
    assert main(["bench", "--tasks", "CartPole-v0", "--peers"]) == 2
    err = capsys.readouterr().err.strip()
    assert "source checkout" in err and "benchmarks/peers.py" in err and "\n" not in err


def test_bad_devices_and_mode_are_user_errors(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["bench", "--tasks", "CartPole-v0", "--devices", "64"]) == 2
    assert "--devices 64" in capsys.readouterr().err
    assert main(["bench", "--tasks", "CartPole-v0", "--modes", "warp"]) == 2
    assert "unknown mode" in capsys.readouterr().err
    assert main(["bench", "--tasks", "NoSuchTask-v0"]) == 2
