"""jaxenvs compiles its programs with its XLA options (jaxenvs.core.xla)."""

from __future__ import annotations

import re
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

import jaxenvs
import jaxenvs.machine
from jaxenvs.core import xla

PACKAGE = Path(jaxenvs.__file__).parent

#: where jaxenvs calls jax.jit itself, and why
PLAIN_JIT = {
    "core/xla.py": "the wrapper itself",
    "core/placement.py": "spread: traced inside its caller's jit, where XLA takes no options",
}


def test_every_program_jaxenvs_compiles_goes_through_its_jit():
    found = {}
    for path in PACKAGE.rglob("*.py"):
        code = [line.split("#")[0] for line in path.read_text().splitlines()]
        calls = [line for line in code if re.search(r"\bjax\.jit\(|@jax\.jit\b", line)]
        calls = [line for line in calls if "``" not in line and '"""' not in line]
        if calls:
            found[path.relative_to(PACKAGE).as_posix()] = calls
    assert set(found) <= set(PLAIN_JIT), {k: v for k, v in found.items() if k not in PLAIN_JIT}


def test_options_are_those_this_xla_takes_and_merge_with_the_callers():
    if jax.__version_info__ < (0, 11):
        assert dict(xla.COMPILER_OPTIONS) == {"xla_cpu_use_fusion_emitters": False}
    assert jaxenvs.machine.COMPILER_OPTIONS is xla.COMPILER_OPTIONS
    x = jnp.arange(6.0)
    compiled = xla.jit(lambda v: jnp.sin(v) * 2).lower(x).compile()
    np.testing.assert_allclose(compiled(x), np.sin(np.arange(6.0)) * 2, rtol=1e-6)
    merged = xla.jit(lambda v: v + 1, compiler_options={"xla_cpu_enable_fast_math": False})
    np.testing.assert_array_equal(merged(x), np.arange(6.0) + 1)


def test_a_batched_env_compiled_by_jaxenvs_jit_steps_like_plain_jit():
    benv = jaxenvs.make("CartPole-v0", num_envs=8, physics="mjx")
    a = jnp.ones(8, jnp.int32)

    def roll(key):
        s = benv.reset(key)
        return jax.lax.fori_loop(0, 30, lambda _, s: benv.step(s, a), s).obs

    ours = jaxenvs.machine.jit(roll)(jax.random.key(0))
    plain = jax.jit(roll)(jax.random.key(0))
    np.testing.assert_allclose(ours, plain, rtol=1e-5, atol=1e-6)


def test_a_program_run_once_is_compiled_without_llvm_optimisations_on_a_cpu(monkeypatch):
    seen = []
    real = jax.jit
    monkeypatch.setattr(jax, "jit", lambda fun, **kw: seen.append(kw) or real(fun, **kw))
    x = jnp.arange(4.0)
    np.testing.assert_array_equal(xla.jit_once(lambda v: v * 3)(x), np.arange(4.0) * 3)
    mine = xla.jit_once(lambda v: v, compiler_options={"xla_backend_optimization_level": 1})
    mine(x)
    assert jax.default_backend() == "cpu"
    assert seen[0]["compiler_options"] == {**xla.COMPILER_OPTIONS, **xla.ONCE_OPTIONS}
    assert seen[1]["compiler_options"]["xla_backend_optimization_level"] == 1  # the caller's
    monkeypatch.setattr(jax, "default_backend", lambda: "gpu")
    xla.jit_once(lambda v: v)
    assert seen[2].get("compiler_options") == (dict(xla.COMPILER_OPTIONS) or None)


def test_a_runs_init_is_compiled_as_a_program_run_once(monkeypatch):
    from jaxenvs.run import programs, run_config

    once = []
    monkeypatch.setattr(programs, "jit_once", lambda fun, **kw: once.append(fun) or xla.jit(fun))
    programs.build_programs.cache_clear()
    resolved = run_config.resolve_config("CartPole-v0", "ppo", agent_overrides={"num_envs": 4})
    try:
        built = programs.build_programs(resolved)
    finally:
        programs.build_programs.cache_clear()
    assert len(once) == 1
    state = built.init_fn(run_config.seed_keys(0, 1))
    assert jax.tree.leaves(state)
