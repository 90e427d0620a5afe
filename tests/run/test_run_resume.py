"""Training guarantees: determinism, resume after any chunk, divergence in the metrics,
one compile of the training chunk.

A tabular resume is tried at every chunk boundary (tests/test_run_checkpoint.py sends a
real SIGINT mid-chunk), and a tiny PPO run on real physics (CartpoleBalance, with a
divergence bound low enough that some envs diverge) is checked for bit-identical repeats
and a Ctrl-C + resume: on the engine ``physics="auto"`` picks (the C engine on a CPU) in
the default tier, on MJX in the full tier. Each trainer is compiled once for the module.
"""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import numpy as np
import pytest
import yaml
from tabular_fakes import chain_run, fake_envs

from jaxenvs.run import checkpoint, loop, programs, runner

TIMING = ("wall_seconds", "cpu_seconds")

PPO_FILE = {
    "algo": "ppo",
    "env": {"id": "CartpoleBalance-v0", "episode_length": 25, "divergence_bound": 0.5},
    "agent": {
        "total_steps": 4 * 16 * 3,  # 3 chunks of one update
        "num_envs": 4,
        "num_steps": 16,
        "updates_per_chunk": 1,
        "update_epochs": 1,
        "num_minibatches": 2,
        "actor_hidden": [16],
        "critic_hidden": [16],
    },
    "train": {"seed": 3, "eval_episodes": 2, "video": False},
}

# past 4.5 the chain's "physics" counts as diverged
CHAIN_FILE = chain_run(chunks=4, num_seeds=2, divergence_bound=4.5)


@pytest.fixture(scope="module")
def traces():
    """Counts the traces of every trainer's init and chunk built by the runner."""
    counts: dict[str, int] = {}
    real_build = runner.build

    def counting(fn, name):
        def traced(*args):
            counts[name] = counts.get(name, 0) + 1
            return fn(*args)

        return traced

    def build(resolved):
        env, trainer = real_build(resolved)
        name = f"{resolved.algo}:{resolved.env_id}:{env.physics}"
        return env, dataclasses.replace(
            trainer,
            init=counting(trainer.init, f"{name}:init"),
            chunk=counting(trainer.chunk, f"{name}:chunk"),
        )

    with pytest.MonkeyPatch.context() as mp, fake_envs():
        mp.setattr(programs, "build", build)  # what build_programs calls
        yield counts


def _resolved(tmp_path_factory, data, name):
    path = tmp_path_factory.mktemp("cfg") / f"{name}.yaml"
    path.write_text(yaml.safe_dump(data))
    return runner.resolve_config(None, None, path)


def _interrupt_at(monkeypatch, n):
    """Ctrl-C inside the runner right after chunk ``n`` is computed, before it commits."""
    real = loop.write_progress
    calls = {"n": 0}

    def write(*args):
        calls["n"] += 1
        if calls["n"] == n:
            raise KeyboardInterrupt
        real(*args)

    monkeypatch.setattr(loop, "write_progress", write)
    return real


def _figures(summary):
    return {k: v for k, v in summary.items() if k not in (*TIMING, "interrupted")}


def _rows(run_dir):
    rows = runner.read_progress(Path(run_dir) / runner.PROGRESS_FILE)
    return [{k: v for k, v in r.items() if k not in TIMING} for r in rows]


def _ckpt(run_dir):
    """The leaves and the metadata but its timings (the checksum covers those too)."""
    leaves, meta = checkpoint.read(Path(run_dir) / runner.CHECKPOINT_FILE)
    timing = ("wall_seconds", "cpu_seconds")
    return leaves, {k: v for k, v in meta["metadata"].items() if k not in timing}


def _same_checkpoint(a, b):
    (la, meta_a), (lb, meta_b) = _ckpt(a), _ckpt(b)
    assert meta_a == meta_b
    for x, y in zip(la, lb, strict=True):
        np.testing.assert_array_equal(x, y)


# ----------------------------------------------------------------------------- PPO
@pytest.fixture(scope="module", params=["auto", pytest.param("mjx", marks=pytest.mark.full)])
def ppo(request, traces, tmp_path_factory):
    data = {**PPO_FILE, "env": {**PPO_FILE["env"], "physics": request.param}}
    resolved = _resolved(tmp_path_factory, data, f"ppo_{request.param}")
    out = tmp_path_factory.mktemp(f"ppo_{request.param}")
    return resolved, out, runner.train(resolved, out, quiet=True)


@pytest.mark.full
def test_ppo_same_seed_and_config_are_bit_identical(ppo, tmp_path):
    resolved, out_a, summary_a = ppo
    summary_b = runner.train(resolved, tmp_path, quiet=True)
    assert _figures(summary_a) == _figures(summary_b)
    on_disk = json.loads((tmp_path / runner.SUMMARY_FILE).read_text())
    assert _figures(on_disk) == _figures(json.loads((out_a / runner.SUMMARY_FILE).read_text()))
    assert _rows(out_a) == _rows(tmp_path)
    _same_checkpoint(out_a, tmp_path)


@pytest.mark.full
def test_ppo_ctrl_c_then_resume_gives_the_same_results(ppo, tmp_path, monkeypatch):
    resolved, out_a, summary_a = ppo
    real = _interrupt_at(monkeypatch, 2)
    with pytest.raises(KeyboardInterrupt):
        runner.train(resolved, tmp_path, quiet=True)
    partial = json.loads((tmp_path / runner.SUMMARY_FILE).read_text())
    assert partial["interrupted"] and partial["chunks"] == 1
    monkeypatch.setattr(loop, "write_progress", real)
    summary = runner.train(runner.load_run_config(tmp_path), tmp_path, resume=True, quiet=True)
    assert _figures(summary) == _figures(summary_a)
    assert _rows(out_a) == _rows(tmp_path)
    _same_checkpoint(out_a, tmp_path)


def test_ppo_in_stages_gives_the_one_program_results_and_resumes(ppo, tmp_path, monkeypatch):
    """The chunk as its rollout's and learning's programs (as an accelerator runs it),
    here on a CPU: under the C engine the results of the chunk as one program, its
    figures, progress rows, checkpoint metadata and integers exactly and its float leaves
    to float32 rounding (XLA fuses the learning step of two programs otherwise than one's,
    and how depends on the processor: on one every leaf agrees bit for bit, on another a
    weight differs in its last bit); under MJX, whose programs XLA fuses otherwise, within
    1e-3. A Ctrl-C and resume reaches the uninterrupted staged run bit for bit."""
    resolved, out_a, summary_a = ppo
    # the programs the run built (their init compiled once for the module), as it asks
    one = programs.build_programs(loop.resolve_scaling(loop.engine_resolved(resolved), None), None)
    stages = programs.StagedChunk(one.trainer.stages, resolved.train.num_seeds)
    staged = dataclasses.replace(one, chunk_fn=stages)
    monkeypatch.setattr(loop, "build_programs", lambda r, d=None: staged)
    whole = runner.train(resolved, tmp_path / "whole", quiet=True)
    if whole["physics"] == "c":
        assert _figures(whole) == _figures(summary_a)
        assert _rows(out_a) == _rows(tmp_path / "whole")
        _close_checkpoint(out_a, tmp_path / "whole", rtol=1e-6, atol=0.0)
    else:
        _close_rows(_rows(out_a), _rows(tmp_path / "whole"))
        _close_checkpoint(out_a, tmp_path / "whole", rtol=1e-3, atol=1e-6)
    real = _interrupt_at(monkeypatch, 2)
    with pytest.raises(KeyboardInterrupt):
        runner.train(resolved, tmp_path / "cut", quiet=True)
    monkeypatch.setattr(loop, "write_progress", real)
    again = runner.load_run_config(tmp_path / "cut")
    summary = runner.train(again, tmp_path / "cut", resume=True, quiet=True)
    assert _figures(summary) == _figures(whole)
    assert _rows(tmp_path / "cut") == _rows(tmp_path / "whole")
    _same_checkpoint(tmp_path / "whole", tmp_path / "cut")


def _close_rows(want, got):
    """progress.csv rows with the same keys and integers, floats within 1e-3 (or 1e-6)."""
    assert [r.keys() for r in want] == [r.keys() for r in got]
    for a, b in zip(want, got, strict=True):
        for k in a:
            if a[k].lstrip("-").isdigit():
                assert a[k] == b[k], k
            else:
                np.testing.assert_allclose(
                    float(b[k]), float(a[k]), rtol=1e-3, atol=1e-6, err_msg=k
                )


def _close_checkpoint(a, b, rtol, atol):
    """The same metadata and integer leaves, float leaves within ``rtol`` (or ``atol``)."""
    (la, meta_a), (lb, meta_b) = _ckpt(a), _ckpt(b)
    assert meta_a == meta_b
    for x, y in zip(la, lb, strict=True):
        if np.issubdtype(x.dtype, np.floating):
            np.testing.assert_allclose(y, x, rtol=rtol, atol=atol)
        else:
            np.testing.assert_array_equal(y, x)


def test_ppo_divergence_is_counted_in_the_run_metrics(ppo):
    _, out_a, summary = ppo
    rows = runner.read_progress(out_a / runner.PROGRESS_FILE)
    diverged = [int(r["diverged"]) for r in rows]
    assert sum(diverged) > 0, rows  # the 0.5 bound is passed by some envs
    assert all(d <= int(r["episodes_in_chunk"]) for d, r in zip(diverged, rows, strict=True))
    assert np.isfinite(summary["eval_mean_return"])
    assert all(np.isfinite(float(r["mean_return"])) for r in rows if r["mean_return"] != "nan")


def test_ppo_chunk_and_init_compile_once(ppo, traces):
    """After fresh runs, a repeat, an interrupted run and its resume."""
    name = f"ppo:CartpoleBalance-v0:{ppo[2]['physics']}"
    assert traces[f"{name}:chunk"] == 1, traces
    assert traces[f"{name}:init"] == 1, traces


# ------------------------------------------------------------------------ tabular
@pytest.fixture(scope="module")
def chain(traces, tmp_path_factory):
    resolved = _resolved(tmp_path_factory, CHAIN_FILE, "chain")
    out = tmp_path_factory.mktemp("chain_a")
    return resolved, out, runner.train(resolved, out, quiet=True)


@pytest.mark.full
@pytest.mark.parametrize("write", [1, 2, 4])
def test_tabular_resume_after_any_chunk(chain, tmp_path, monkeypatch, write):
    """Ctrl-C after chunk ``write`` is computed leaves chunk ``write - 1`` on disk."""
    resolved, out_a, summary_a = chain
    real = _interrupt_at(monkeypatch, write)
    with pytest.raises(KeyboardInterrupt):
        runner.train(resolved, tmp_path, quiet=True)
    leaves, meta = checkpoint.read(tmp_path / runner.CHECKPOINT_FILE)
    assert meta["metadata"]["chunk"] == write - 1
    assert json.loads((tmp_path / runner.SUMMARY_FILE).read_text())["chunks"] == write - 1
    monkeypatch.setattr(loop, "write_progress", real)
    summary = runner.train(runner.load_run_config(tmp_path), tmp_path, resume=True, quiet=True)
    assert _figures(summary) == _figures(summary_a)
    assert _rows(out_a) == _rows(tmp_path)
    _same_checkpoint(out_a, tmp_path)


def test_tabular_divergence_is_counted_and_compiled_once(chain, traces):
    _, out_a, _ = chain
    rows = runner.read_progress(out_a / runner.PROGRESS_FILE)
    assert sum(int(r["diverged"]) for r in rows) > 0
    assert traces["qlearning:Test-Chain-v0:mjx:chunk"] == 1, traces  # the fakes' "engine"
