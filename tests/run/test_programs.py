"""A run's programs: one seed traced without the seed axis, the evaluator compiled only
once the first chunk has, a chunk run in stages."""

from __future__ import annotations

import concurrent.futures
import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import pytest
import yaml
from tabular_fakes import chain_run, fake_envs

from jaxenvs.agents.base import Stages
from jaxenvs.run import loop, programs, runner

CHAIN_FILE = chain_run(chunks=3, num_seeds=1)  # one seed: init and chunk by over_seeds


def _loop(carry, x):
    """A function with a loop over a carry, as a chunk has (the seed axis's batching rule
    would batch its body), a typed key and a ``None`` leaf."""

    def body(c, _):
        return c * 0.5 + x["a"], c.sum()

    out, sums = jax.lax.scan(body, carry, None, length=4)
    return {"out": out, "sums": sums, "key": jax.random.split(x["key"])[0], "none": None}


def _inputs(seeds):
    carry = jnp.arange(seeds * 2, dtype=jnp.float32).reshape(seeds, 2)
    keys = jax.random.split(jax.random.key(0), seeds)
    return carry, {"a": jnp.linspace(0.0, 1.0, seeds), "key": keys, "none": None}


@pytest.mark.parametrize("seeds", [1, 3])
def test_over_seeds_maps_the_leading_axis_as_vmap_does(seeds):
    got = jax.jit(programs.over_seeds(_loop, seeds))(*_inputs(seeds))
    want = jax.vmap(_loop)(*_inputs(seeds))
    assert jax.tree.structure(got) == jax.tree.structure(want)
    for g, w in zip(jax.tree.leaves(got), jax.tree.leaves(want), strict=True):
        assert g.shape == w.shape  # the seed axis is kept for one seed too
        if jax.dtypes.issubdtype(g.dtype, jax.dtypes.prng_key):
            g, w = jax.random.key_data(g), jax.random.key_data(w)
        np.testing.assert_allclose(g, w, rtol=1e-6)


def test_one_seed_is_the_function_itself_not_a_vmap():
    def plain(carry, x):  # drop the seed axis, call, restore it
        out = _loop(*jax.tree.map(lambda a: a[0], (carry, x)))
        return jax.tree.map(lambda a: a[None], out)

    args = _inputs(1)
    one = str(jax.make_jaxpr(programs.over_seeds(_loop, 1))(*args))
    assert one == str(jax.make_jaxpr(plain)(*args))
    assert one != str(jax.make_jaxpr(jax.vmap(_loop))(*args))
    assert str(jax.make_jaxpr(programs.over_seeds(_loop, 3))(*_inputs(3))) == str(
        jax.make_jaxpr(jax.vmap(_loop))(*_inputs(3))
    )


class _Recording(concurrent.futures.ThreadPoolExecutor):
    """The background compile thread, noting when each job was submitted."""

    def __init__(self, events):
        super().__init__(1)
        self.events = events

    def submit(self, fn, /, *args, **kwargs):
        chunk = isinstance(getattr(fn, "__self__", None), programs.BackgroundChunk)
        self.events.append("chunk compile" if chunk else "submitted")
        return super().submit(fn, *args, **kwargs)


@pytest.fixture
def chain(tmp_path):
    path = tmp_path / "chain.yaml"
    path.write_text(yaml.safe_dump(CHAIN_FILE))
    with fake_envs():
        yield runner.resolve_config(None, None, path)


@pytest.fixture
def events(monkeypatch):
    """The submits to a recording background thread, with no programs cached before or
    after (their compiles would have gone to it)."""
    seen: list[str] = []
    executor = _Recording(seen)
    monkeypatch.setattr(programs, "_COMPILER", executor)
    programs.build_programs.cache_clear()
    yield seen
    programs.build_programs.cache_clear()
    executor.shutdown()


class _CountedChunk:
    """A run's chunk that notes each call (its compile's start passed on)."""

    def __init__(self, chunk, events):
        self.chunk, self.events = chunk, events

    def start(self, state):
        self.chunk.start(state)

    def __call__(self, state):
        self.events.append("chunk")
        return self.chunk(state)

    def eval_shape(self, state):
        return self.chunk.eval_shape(state)


def test_evaluator_compiles_once_after_the_first_chunk(chain, events, tmp_path, monkeypatch):
    progs = programs.build_programs(chain)
    assert events == []  # building compiles no evaluator
    counted = dataclasses.replace(progs, chunk_fn=_CountedChunk(progs.chunk_fn, events))
    monkeypatch.setattr(loop, "build_programs", lambda *a, **k: counted)
    summary = runner.train(chain, tmp_path / "run", quiet=True)
    # the chunk's compile starts before init runs; the evaluator's after the first chunk
    assert events[:3] == ["chunk compile", "chunk", "submitted"]
    assert events.count("submitted") == 1  # every chunk asks; one compile
    assert events.count("chunk compile") == 1
    assert events.count("chunk") == 3
    assert len(summary["eval_mean_return_per_seed"]) == 1


def test_an_evaluator_that_fails_to_compile_fails_the_evaluation(chain, events):
    def broken():
        raise RuntimeError("the evaluator did not compile")

    progs = dataclasses.replace(
        programs.build_programs(chain), evaluator=programs.BackgroundCompile(broken)
    )
    progs.start_evaluator()
    for _ in range(2):  # the compile's error, each time it is asked for
        with pytest.raises(RuntimeError, match="did not compile"):
            progs.evaluate(None, jax.random.key(0))
    assert events == ["submitted"]  # started once, not retried


PPO_AGENT = {
    "num_envs": 4,
    "num_steps": 8,
    "updates_per_chunk": 2,
    "update_epochs": 1,
    "num_minibatches": 2,
    "actor_hidden": [8],
    "critic_hidden": [8],
}


def test_a_staged_chunk_compiles_before_its_call_and_is_the_chunk(events):
    """Its two compiles are submitted when the run loop starts them, before ``init``
    runs, and its results over several seeds are the one-program chunk's on a CPU."""
    train = {"num_seeds": 2, "video": False}
    resolved = runner.resolve_config("CartPole-v0", "ppo", None, PPO_AGENT, train)
    progs = programs.build_programs(resolved, None, True)
    assert isinstance(progs.chunk_fn, programs.StagedChunk)
    keys = runner.seed_keys(0, 2)
    progs.start_chunk(progs.init_fn.eval_shape(keys))
    assert events == ["submitted"] * 2  # the rollout's, and the learning's with finish's
    one = jax.jit(jax.vmap(progs.trainer.chunk))
    staged = want = progs.init_fn(keys)
    for _ in range(2):
        staged, got_metrics = progs.chunk_fn(staged)
        want, want_metrics = one(want)
    assert events == ["submitted"] * 2  # compiled once
    assert jax.tree.structure(got_metrics) == jax.tree.structure(want_metrics)
    got, want = jax.tree.leaves((staged, got_metrics)), jax.tree.leaves((want, want_metrics))
    for g, w in zip(got, want, strict=True):
        if jax.dtypes.issubdtype(g.dtype, jax.dtypes.prng_key):
            g, w = jax.random.key_data(g), jax.random.key_data(w)
        np.testing.assert_array_equal(g, w)


def test_a_one_program_chunk_compiles_before_its_call_and_is_the_chunk(events):
    """Started by the run loop before ``init`` runs, its compile is submitted once; its
    results are the jitted chunk's, bit for bit, for states whose weak types differ."""
    resolved = runner.resolve_config("CartPole-v0", "ppo", None, PPO_AGENT, {"video": False})
    progs = programs.build_programs(resolved, None, False)
    assert isinstance(progs.chunk_fn, programs.BackgroundChunk)
    keys = runner.seed_keys(0, 1)
    progs.start_chunk(progs.init_fn.eval_shape(keys))
    assert events == ["chunk compile"]
    one = jax.jit(programs.over_seeds(progs.trainer.chunk, 1))
    got = want = progs.init_fn(keys)
    for _ in range(2):
        got, got_metrics = progs.chunk_fn(got)
        want, want_metrics = one(want)
    assert events == ["chunk compile"]  # compiled once
    got, want = jax.tree.leaves((got, got_metrics)), jax.tree.leaves((want, want_metrics))
    for g, w in zip(got, want, strict=True):
        if jax.dtypes.issubdtype(g.dtype, jax.dtypes.prng_key):
            g, w = jax.random.key_data(g), jax.random.key_data(w)
        np.testing.assert_array_equal(g, w)


def test_a_one_program_chunk_whose_compile_failed_compiles_again_on_the_next_call():
    calls = []

    def chunk(state):
        calls.append("trace")
        if len(calls) == 1:
            raise RuntimeError("the chunk did not compile")
        return state + 1.0, {"sum": state.sum()}

    background = programs.BackgroundChunk(jax.jit(chunk))
    state = jnp.ones((1, 3), jnp.float32)
    with pytest.raises(RuntimeError, match="did not compile"):
        background(state)
    state, metrics = background(state)
    np.testing.assert_array_equal(state, [[2.0, 2.0, 2.0]])
    np.testing.assert_array_equal(metrics["sum"], 3.0)
    weak = jnp.broadcast_to(jnp.asarray(2.0), (1, 3))  # weakly typed: the same program
    assert weak.weak_type
    np.testing.assert_array_equal(background(weak)[0], [[3.0, 3.0, 3.0]])
    assert calls == ["trace", "trace"]


@pytest.mark.parametrize(("backend", "staged"), [("cpu", False), ("gpu", True), ("tpu", True)])
def test_a_chunk_runs_in_stages_by_default_on_an_accelerator(monkeypatch, backend, staged):
    monkeypatch.setattr(jax, "default_backend", lambda: backend)
    assert programs.default_staged() is staged


def test_a_staged_chunk_whose_compile_failed_compiles_again_on_the_next_call():
    traces = []

    def collect(state):
        traces.append("collect")
        if len(traces) == 1:
            raise RuntimeError("the rollout did not compile")
        return state + 1.0, state

    stages = Stages(
        collect=collect,
        learn=lambda state, batch: (state + batch, {"x": batch.sum()}),
        finish=lambda state, m: {"x": m["x"].sum(), "last": state.sum()},
        count=2,
    )
    chunk = programs.StagedChunk(stages, 1)
    state = jnp.ones((1, 3), jnp.float32)
    with pytest.raises(RuntimeError, match="did not compile"):
        chunk(state)
    state, metrics = chunk(state)  # 1 -> 2 + 1 = 3 -> 4 + 3 = 7; batches' sums 3 and 9
    np.testing.assert_array_equal(state, [[7.0, 7.0, 7.0]])
    np.testing.assert_array_equal(metrics["x"], [12.0])
    np.testing.assert_array_equal(metrics["last"], [21.0])
