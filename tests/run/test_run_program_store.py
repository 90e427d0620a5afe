"""Stored traced programs: round trip, keys, damaged files, and warm training runs."""

from __future__ import annotations

import dataclasses
import os
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from tabular_fakes import fake_envs

from jaxenvs.core.xla import jit
from jaxenvs.run import checkpoint, compile_cache, program_store, programs, run_config, runner


class Carry(NamedTuple):
    key: jax.Array
    total: jax.Array


def _walk(carry: Carry, scale: jax.Array) -> tuple[Carry, dict[str, jax.Array]]:
    key, sub = jax.random.split(carry.key)
    step = scale * jax.random.normal(sub, carry.total.shape)
    return Carry(key, carry.total + step), {"mean": jnp.mean(step)}


def _args() -> tuple[Carry, jax.Array]:
    return Carry(jax.random.key(3), jnp.zeros(4)), jnp.float32(0.5)


def _store(tmp_path, config=None, fn=_walk, known=None) -> program_store.Program:
    return program_store.load_or_export(
        fn,
        _args(),
        name="walk",
        config=config or {"a": 1},
        directory=tmp_path,
        jit=jit,
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
    _same(first(*_args()), expected)
    _same(second(*_args()), expected)
    # custom pytree nodes and PRNG keys come back as they went in
    out = second(*_args())
    assert isinstance(out[0], Carry) and set(out[1]) == {"mean"}
    assert jax.tree.structure(second.out_shape) == jax.tree.structure(expected)
    # the output's shapes without a trace, for arguments like the stored ones only
    assert second.eval_shape(*_args()) is second.out_shape
    with pytest.raises(ValueError, match="do not match"):
        second.eval_shape(Carry(jax.random.key(3), jnp.zeros(5)), jnp.float32(0.5))


def test_key_covers_config_shapes_settings_and_source(tmp_path, monkeypatch):
    _store(tmp_path, {"a": 1})
    assert _store(tmp_path, {"a": 2}).loaded is False  # another config, another program
    key = program_store.program_key
    other = (Carry(jax.random.key(0), jnp.zeros(5)), jnp.float32(0.5))
    assert key("walk", {"a": 1}, other) != key("walk", {"a": 1}, _args())
    weak = (_args()[0], 0.5)  # a weakly typed scalar traces another program
    assert key("walk", {"a": 1}, jax.tree.map(jnp.asarray, weak)) != key("walk", {"a": 1}, _args())
    before = key("walk", {"a": 1}, _args())
    monkeypatch.setattr(program_store, "source_digest", lambda: "edited")
    assert key("walk", {"a": 1}, _args()) != before
    monkeypatch.undo()
    args = _args()
    old = jax.config.jax_default_matmul_precision
    jax.config.update("jax_default_matmul_precision", "highest")
    try:  # a setting that changes what a trace makes, the arguments the same
        assert key("walk", {"a": 1}, args) != before
    finally:
        jax.config.update("jax_default_matmul_precision", old)
    assert key("walk", {"a": 1}, args) == before


def test_source_digest_covers_every_subpackage():
    """A change to a task, the engines, the agents or the native engine's source makes a
    new key, not only a change to the run package."""
    package = program_store._PACKAGE
    names = {p.relative_to(package).as_posix() for p in program_store.source_files()}
    for name in (
        "run/programs.py",
        "agents/ppo/__init__.py",
        "core/env.py",
        "physics/cengine.py",
        "physics/native/engine.cc",
        "tasks/cartpole.py",
        "scenes/terrain.py",
        "configs/ppo_CartPole-v0.yaml",
    ):
        assert name in names, name
    assert any(p.suffix == ".xml" for p in program_store.source_files())


def test_output_of_unknown_structure_is_not_stored(tmp_path):
    with pytest.warns(UserWarning, match="could not store program"):
        program = _store(tmp_path, known=())  # Carry is a custom node nobody described
    assert not list(tmp_path.glob("*.jaxexport"))
    _same(program(*_args()), jax.jit(_walk)(*_args()))


def test_file_is_json_and_a_module_not_pickle(tmp_path):
    _store(tmp_path)
    (path,) = tmp_path.glob("walk-*.jaxexport")
    blob = path.read_bytes()
    assert blob.startswith(program_store.MAGIC)
    assert b'"out": {"tuple": [{"known": 0}, {"dict": [["mean"], ["*"]]}]}' in blob


def _damage_truncate(path) -> None:
    path.write_bytes(path.read_bytes()[: path.stat().st_size // 2])


def _damage_flip(path) -> None:
    blob = bytearray(path.read_bytes())
    blob[len(blob) // 2] ^= 0x5A
    path.write_bytes(bytes(blob))


@pytest.mark.parametrize("damage", [_damage_truncate, _damage_flip])
def test_damaged_file_costs_a_trace_and_a_warning(tmp_path, damage):
    _store(tmp_path)
    (path,) = tmp_path.glob("walk-*.jaxexport")
    assert path.read_bytes().startswith(program_store.MAGIC)
    damage(path)
    with pytest.warns(UserWarning, match="discarding damaged stored program"):
        again = _store(tmp_path)
    assert not again.loaded
    _same(again(*_args()), jax.jit(_walk)(*_args()))
    assert _store(tmp_path).loaded  # stored again, whole


def test_another_keys_file_is_refused(tmp_path):
    _store(tmp_path, {"a": 1})
    (path,) = tmp_path.glob("walk-*.jaxexport")
    _store(tmp_path, {"a": 2})
    (other,) = set(tmp_path.glob("walk-*.jaxexport")) - {path}
    other.write_bytes(path.read_bytes())  # a's program under b's name
    with pytest.warns(UserWarning, match="another key's program"):
        assert not _store(tmp_path, {"a": 2}).loaded


def test_unwritable_store_still_runs_the_program(tmp_path):
    blocker = tmp_path / "file"
    blocker.write_text("")
    with pytest.warns(UserWarning, match="could not store program"):
        program = program_store.load_or_export(
            _walk, _args(), name="walk", config={}, directory=blocker / "sub", jit=jit,
            known=(_args()[0],),
        )  # fmt: skip
    _same(program(*_args()), jax.jit(_walk)(*_args()))


def test_store_keeps_the_recently_used_within_its_size(tmp_path):
    for name in ("a", "b", "c", "new", ".tmp-writing"):
        (tmp_path / f"{name}.jaxexport").write_bytes(b"x" * 100)
    os.utime(tmp_path / "a.jaxexport", ns=(1, 1))  # least recently used
    os.utime(tmp_path / "b.jaxexport", ns=(3, 3))
    os.utime(tmp_path / "c.jaxexport", ns=(2, 2))
    os.utime(tmp_path / "new.jaxexport", ns=(0, 0))  # just stored: never removed
    removed = program_store.prune(tmp_path, 250, keep=tmp_path / "new.jaxexport")
    assert [p.name for p in removed] == ["a.jaxexport", "c.jaxexport"]
    left = sorted(p.name for p in tmp_path.iterdir())
    assert left == [".tmp-writing.jaxexport", "b.jaxexport", "new.jaxexport"]
    assert program_store.prune(tmp_path, 250) == []


def test_loading_a_program_marks_it_recently_used(tmp_path):
    _store(tmp_path)
    (path,) = tmp_path.glob("walk-*.jaxexport")
    os.utime(path, ns=(1, 1))
    assert _store(tmp_path).loaded
    assert path.stat().st_mtime_ns > 1


def test_weak_arguments_and_unexportable_functions_are_not_stored(tmp_path):
    weak = program_store.load_or_export(
        _walk, (_args()[0], jnp.asarray(0.5)), name="weak", config={}, directory=tmp_path,
        jit=jit, known=(_args()[0],),
    )  # fmt: skip
    assert weak is None

    def printing(carry, scale):
        jax.debug.callback(lambda s: None, scale)  # a host callback: jax.export refuses it
        return _walk(carry, scale)

    with pytest.warns(UserWarning, match="is not stored"):
        assert _store(tmp_path, fn=printing) is None
    assert not list(tmp_path.glob("*.jaxexport"))


def test_arguments_of_another_structure_are_refused(tmp_path):
    program = _store(tmp_path)
    with pytest.raises(ValueError, match="do not match"):
        program((jax.random.key(3), jnp.zeros(4)), jnp.float32(0.5))


def _spy(monkeypatch) -> list[tuple[str, bool]]:
    """Records ``(name, loaded)`` of every program the run's store returns."""
    seen: list[tuple[str, bool]] = []
    real = program_store.load_or_export

    def spy(*args, **kwargs):
        program = real(*args, **kwargs)
        seen.append((kwargs["name"].rsplit("-", 1)[-1], program.loaded))
        return program

    monkeypatch.setattr(program_store, "load_or_export", spy)
    return seen


def test_user_tasks_and_algorithms_are_not_stored(tmp_path, monkeypatch):
    """A task or an algorithm defined outside the package is not covered by the key:
    nothing is stored."""
    monkeypatch.setattr(compile_cache, "active", lambda: tmp_path / "cache")
    with fake_envs():
        resolved = runner.resolve_config(
            "Test-Chain-v0", "qlearning", None, {"number_splits": 7, "obs_low": [0.0],
            "obs_high": [7.0]}, {}
        )  # fmt: skip
        env, _ = runner.build(resolved)
        assert programs.program_store_for(resolved, env) is None
    resolved = runner.resolve_config("CartPole-v0", "qlearning", None, {"num_envs": 4}, {})
    resolved = runner.engine_resolved(resolved)
    env, _ = runner.build(resolved)
    assert programs.program_store_for(resolved, env) is not None
    user = dataclasses.replace(run_config.ALGORITHMS["qlearning"], module="my_algorithms")
    monkeypatch.setitem(run_config.ALGORITHMS, "qlearning", user)
    assert programs.program_store_for(resolved, env) is None


def test_the_c_engines_threads_and_fields_are_in_the_key():
    """The native call's thread count and derived fields are attributes of the stored
    program, not of the config: they are in its key."""
    resolved = runner.resolve_config("CartPole-v0", "qlearning", None, {"num_envs": 4}, {})
    resolved = runner.engine_resolved(resolved)
    env, _ = runner.build(resolved)
    settings = programs.store_settings(resolved, env)
    assert settings is not None and settings["engine"]["physics"] == "c"
    assert settings["engine"]["threads"] == env.sim.engine.threads
    assert "derived" in settings["engine"] and "seed" not in settings["train"]


def test_warm_training_run_loads_its_programs_and_matches(tmp_path, monkeypatch):
    """A second run of a config loads init, chunk and evaluator instead of tracing them,
    and trains to the first run's state and curve, bit for bit."""
    # the persistent compile cache stays off (process-wide); only the program store is on,
    # for the physics-free chain task of the test fakes (fast to compile)
    monkeypatch.setattr(compile_cache, "active", lambda: tmp_path / "cache")
    monkeypatch.setattr(programs, "STORE_MODULES", ("jaxenvs.", "tabular_fakes"))
    seen = _spy(monkeypatch)
    agent = dict(
        alpha=0.5, gamma=0.9, number_splits=7, obs_low=[0.0], obs_high=[7.0],
        num_envs=2, chunk_steps=30, total_steps=2 * 30 * 3,
    )  # fmt: skip
    outs = []
    with fake_envs():
        resolved = runner.resolve_config(
            "Test-Chain-v0", "qlearning", None, agent, dict(eval_episodes=3, video=False)
        )
        for name in ("cold", "warm", "off"):
            if name == "off":  # the store off: the programs traced and compiled as usual
                monkeypatch.setattr(compile_cache, "active", lambda: None)
            runner.build_programs.cache_clear()
            outs.append(tmp_path / name)
            runner.train(resolved, outs[-1], quiet=True)
    runner.build_programs.cache_clear()
    # init, chunk and eval (the eval on a background thread): traced cold, loaded warm
    assert sorted(seen[:3]) == [("chunk", False), ("eval", False), ("init", False)]
    assert sorted(seen[3:]) == [("chunk", True), ("eval", True), ("init", True)]
    stored = sorted(p.name.split("-")[-2] for p in (tmp_path / "cache/programs").iterdir())
    assert stored == ["chunk", "eval", "init"]
    assert len(seen) == 6  # nothing asked of the store with it off
    a, b, c = (checkpoint.read(o / runner.CHECKPOINT_FILE)[0] for o in outs)
    for x, y, z in zip(a, b, c, strict=True):
        np.testing.assert_array_equal(x, y)
        np.testing.assert_array_equal(x, z)
    rows = [runner.read_progress(o / runner.PROGRESS_FILE) for o in outs]
    returns = [[r["mean_return"] for r in row] for row in rows]
    assert returns[0] == returns[1] == returns[2]


@pytest.mark.full
def test_c_engine_programs_are_stored_and_loaded(tmp_path, monkeypatch):
    """Programs that step the native C engine name the model by its digest, so they are
    stored and a second run loads them and trains to the same state (the callback path's
    programs are not stored)."""
    from jaxenvs.physics import native

    monkeypatch.setattr(compile_cache, "active", lambda: tmp_path / "cache")
    seen = _spy(monkeypatch)
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
        assert seen == []  # nothing stored on the callback path
        return
    assert [loaded for _, loaded in seen] == [False] * 3 + [True] * 3
    a, b = (checkpoint.read(o / runner.CHECKPOINT_FILE)[0] for o in outs)
    for x, y in zip(a, b, strict=True):
        np.testing.assert_array_equal(x, y)
