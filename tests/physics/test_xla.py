"""jaxenvs compiles its programs with its XLA options (jaxenvs.core.xla)."""

from __future__ import annotations

import re
from pathlib import Path
from typing import Any

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
    "run/program_store.py": "jax.export's trace, never compiled (the wrapper is, by its jit)",
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
    x = jnp.arange(4.0)
    np.testing.assert_array_equal(xla.jit_once(lambda v: v * 3)(x), np.arange(4.0) * 3)
    seen = []
    real = xla.jit
    monkeypatch.setattr(xla, "jit", lambda fun, **kw: seen.append(kw) or real(fun, **kw))
    monkeypatch.setattr(jax, "default_backend", lambda: "cpu")
    xla.jit_once(lambda v: v)
    xla.jit_once(lambda v: v, compiler_options={"xla_backend_optimization_level": 1}, inline=True)
    monkeypatch.setattr(jax, "default_backend", lambda: "gpu")
    xla.jit_once(lambda v: v, inline=True)
    assert seen[0] == {"compiler_options": dict(xla.ONCE_OPTIONS)}
    assert seen[1] == {"compiler_options": {"xla_backend_optimization_level": 1}, "inline": True}
    assert seen[2] == {"inline": True}  # elsewhere exactly jit


def _recording(made: list) -> Any:
    """A stand-in for ``jit_once`` that records what it makes."""

    def fake(fun: Any, **kwargs: Any) -> Any:
        made.append(xla.jit(fun, **kwargs))
        return made[-1]

    return fake


def test_a_runs_init_is_compiled_as_a_program_run_once(monkeypatch):
    from jaxenvs.run import programs, run_config

    made: list = []
    monkeypatch.setattr(programs, "jit_once", _recording(made))
    programs.build_programs.cache_clear()
    resolved = run_config.resolve_config("CartPole-v0", "ppo", agent_overrides={"num_envs": 4})
    try:
        built = programs.build_programs(resolved, devices=1, staged=False)
    finally:
        programs.build_programs.cache_clear()
    assert len(made) == 1 and built.init_fn is made[0]
    assert built.chunk_fn.chunk is not made[0]
    assert jax.tree.leaves(built.init_fn(run_config.seed_keys(0, 1)))


_MESH_INITS = """
import sys
from jaxenvs.run import placement, programs, run_config
sys.path.insert(0, sys.argv[1])
from test_xla import _recording
made = []
placement.jit_once = _recording(made)
for algo, seeds in (("ppo", 1), ("ppo", 2), ("qlearning", 1)):
    resolved = run_config.resolve_config(
        "CartPole-v0", algo, agent_overrides={"num_envs": 4}, train_overrides={"num_seeds": seeds}
    )
    built = programs.build_programs(resolved, devices=2)
    assert built.init_fn is made[-1], (algo, seeds)
assert len(made) == 3, made
"""


def test_a_runs_init_over_host_devices_is_compiled_as_a_program_run_once():
    """Every layout of a run over several devices (the PPO trainer's own mesh, seeds
    over devices, a sharded trainer) compiles its init with ``jit_once``."""
    from host_devices import run_with_devices

    run_with_devices(2, _MESH_INITS, [str(Path(__file__).parent)])
