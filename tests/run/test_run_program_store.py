"""Stored traced programs: round trip, keys, damaged files, and a warm training run."""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from tabular_fakes import fake_envs

from jaxenvs.run import checkpoint, compile_cache, program_cache, programs, runner


class Carry(NamedTuple):
    key: jax.Array
    total: jax.Array


def _walk(carry: Carry, scale: jax.Array) -> tuple[Carry, dict[str, jax.Array]]:
    key, sub = jax.random.split(carry.key)
    step = scale * jax.random.normal(sub, carry.total.shape)
    return Carry(key, carry.total + step), {"mean": jnp.mean(step)}


def _args() -> tuple[Carry, jax.Array]:
    return Carry(jax.random.key(3), jnp.zeros(4)), jnp.float32(0.5)


def _store(tmp_path, config=None, fn=_walk, known=None):
    return program_cache.load_or_export(
        fn,
        _args(),
        name="walk",
        config=config or {"a": 1},
        directory=tmp_path,
        known=(_args()[0],) if known is None else known,
    )


def _same(a, b) -> None:
    for x, y in zip(jax.tree.leaves(a), jax.tree.leaves(b), strict=True):
        if jnp.issubdtype(x.dtype, jax.dtypes.prng_key):
            x, y = jax.random.key_data(x), jax.random.key_data(y)
        np.testing.assert_array_equal(np.asarray(x), np.asarray(y))


def test_stored_program_round_trip(tmp_path):
    first = _store(tmp_path)
    second = _store(tmp_path)
    assert not first.loaded and second.loaded
    assert len(list(tmp_path.glob("walk-*.jaxexport"))) == 1
    expected = jax.jit(_walk)(*_args())
    _same(first.call(*_args()), expected)
    _same(second.call(*_args()), expected)
    # custom pytree nodes and PRNG keys come back as they went in
    out = second.call(*_args())
    assert isinstance(out[0], Carry) and set(out[1]) == {"mean"}
    assert jax.tree.structure(second.out_shape) == jax.tree.structure(expected)


def test_key_covers_config_shapes_and_source(tmp_path, monkeypatch):
    _store(tmp_path, {"a": 1})
    assert _store(tmp_path, {"a": 2}).loaded is False  # another config, another program
    other = (Carry(jax.random.key(0), jnp.zeros(5)), jnp.float32(0.5))
    key = program_cache.program_key
    assert key("walk", {"a": 1}, other) != key("walk", {"a": 1}, _args())
    before = key("walk", {"a": 1}, _args())
    monkeypatch.setitem(program_cache._environment(), "source", "edited")
    assert key("walk", {"a": 1}, _args()) != before


def test_source_digest_covers_every_subpackage():
    """A change to a task, the engines, the agents or the native engine's source makes a
    new key, not only a change to the run package."""
    names = {p.relative_to(program_cache._PACKAGE).as_posix() for p in program_cache.source_files()}
    for name in (
        "run/programs.py",
        "agents/ppo.py",
        "core/env.py",
        "physics/cengine.py",
        "physics/native/engine.cc",
        "tasks/cartpole.py",
        "robots/cartpole/cartpole.xml",
        "configs/ppo_CartPole-v0.yaml",
    ):
        assert name in names, name


def test_output_of_unknown_structure_is_not_stored(tmp_path):
    with pytest.warns(UserWarning, match="could not store program"):
        program = _store(tmp_path, known=())  # Carry is a custom node nobody described
    assert not list(tmp_path.glob("*.jaxexport"))
    _same(program.call(*_args()), jax.jit(_walk)(*_args()))


def test_file_is_not_pickle_and_names_its_output(tmp_path):
    _store(tmp_path)
    (path,) = tmp_path.glob("walk-*.jaxexport")
    assert path.read_bytes().startswith(program_cache.MAGIC)


def test_arguments_of_another_structure_are_refused(tmp_path):
    program = _store(tmp_path)
    with pytest.raises(ValueError, match="do not match"):
        program.call((jax.random.key(3), jnp.zeros(4)), jnp.float32(0.5))


@pytest.mark.full
def test_warm_training_run_loads_its_programs_and_matches(tmp_path, monkeypatch):
    # the persistent compile cache stays off (process-wide); only the program store is on,
    # for the physics-free chain task of the test fakes (fast to compile)
    monkeypatch.setattr(compile_cache, "active", lambda: tmp_path / "cache")
    monkeypatch.setattr(programs, "STORE_MODULES", ("jaxenvs.", "tabular_fakes"))
    loaded: list[bool] = []
    real = program_cache.load_or_export

    def spy(*args, **kwargs):
        program = real(*args, **kwargs)
        loaded.append(program.loaded)
        return program

    monkeypatch.setattr(program_cache, "load_or_export", spy)
    agent = dict(
        alpha=0.5, gamma=0.9, number_splits=7, obs_low=[0.0], obs_high=[7.0],
        num_envs=2, chunk_steps=30, total_steps=2 * 30 * 3,
    )  # fmt: skip
    outs = []
    with fake_envs():
        resolved = runner.resolve_config(
            "Test-Chain-v0", "qlearning", None, agent, dict(eval_episodes=3, video=False)
        )
        for name in ("cold", "warm"):
            runner.build_programs.cache_clear()
            outs.append(tmp_path / name)
            runner.train(resolved, outs[-1], quiet=True)
    runner.build_programs.cache_clear()
    # init, chunk and eval (the eval on a background thread): traced cold, loaded warm
    assert loaded == [False] * 3 + [True] * 3
    stored = sorted(p.name.split("-")[-2] for p in (tmp_path / "cache/programs").iterdir())
    assert stored == ["chunk", "eval", "init"]
    a, b = (checkpoint.read(o / runner.CHECKPOINT_FILE)[0] for o in outs)
    for x, y in zip(a, b, strict=True):
        np.testing.assert_array_equal(x, y)
    rows = [runner.read_progress(o / runner.PROGRESS_FILE) for o in outs]
    assert [r["mean_return"] for r in rows[0]] == [r["mean_return"] for r in rows[1]]


def test_user_tasks_are_not_stored(tmp_path, monkeypatch):
    """A task defined outside the package is not covered by the key: nothing is stored."""
    monkeypatch.setattr(compile_cache, "active", lambda: tmp_path / "cache")
    with fake_envs():
        resolved = runner.resolve_config(
            "Test-Chain-v0", "qlearning", None, {"number_splits": 7, "obs_low": [0.0],
            "obs_high": [7.0]}, {}
        )  # fmt: skip
        env, trainer = runner.build(resolved)
        assert runner.program_store(resolved, env, trainer) is None


@pytest.mark.full
def test_c_engine_programs_are_stored_and_loaded(tmp_path, monkeypatch):
    """Programs that step the native C engine name the model by its digest, so they are
    stored and a second run loads them (the callback path's programs are not stored)."""
    from jaxenvs.physics import native

    monkeypatch.setattr(compile_cache, "active", lambda: tmp_path / "cache")
    loaded: list[bool] = []
    real = program_cache.load_or_export

    def spy(*args, **kwargs):
        program = real(*args, **kwargs)
        loaded.append(program.loaded)
        return program

    monkeypatch.setattr(program_cache, "load_or_export", spy)
    agent = dict(num_envs=4, chunk_steps=20, total_steps=4 * 20 * 2)
    resolved = runner.resolve_config(
        "CartPole-v0", "qlearning", None, agent, dict(eval_episodes=2, video=False)
    )
    resolved = runner.engine_resolved(resolved)
    assert resolved.env.physics == "c"
    outs = []
    for name in ("cold", "warm"):
        runner.build_programs.cache_clear()
        outs.append(tmp_path / name)
        runner.train(resolved, outs[-1], quiet=True)
    runner.build_programs.cache_clear()
    if not native.available():
        assert loaded == []  # nothing stored on the callback path
        return
    assert loaded == [False] * 3 + [True] * 3
    a, b = (checkpoint.read(o / runner.CHECKPOINT_FILE)[0] for o in outs)
    for x, y in zip(a, b, strict=True):
        np.testing.assert_array_equal(x, y)
