"""The modules of jaxenvs import each other without a cycle (read from the source, no JAX),
and ``import jaxenvs`` leaves ``mujoco.mjx`` to the first model built (a fresh process)."""

from __future__ import annotations

import ast
import subprocess
import sys
from pathlib import Path

import pytest

PACKAGE = Path(__file__).resolve().parents[2] / "jaxenvs"


def _module_name(path: Path) -> str:
    parts = path.relative_to(PACKAGE.parent).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def _modules() -> dict[str, Path]:
    return {_module_name(p): p for p in sorted(PACKAGE.rglob("*.py"))}


def _imported(tree: ast.AST, name: str, is_package: bool, modules: set[str]) -> set[str]:
    """The modules of ``modules`` that ``name``'s source imports anywhere (module or
    function level): ``import a.b``; ``from a import b`` as ``a.b`` where that is a module,
    else as ``a`` (relative imports resolved); ``importlib.import_module("a.b")`` with a
    string literal."""
    package = name if is_package else name.rpartition(".")[0]
    found: set[str] = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            found.update(alias.name for alias in node.names)
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                parts = package.split(".")
                anchor = ".".join(parts[: len(parts) - node.level + 1])
                base = f"{anchor}.{base}" if base else anchor
            for alias in node.names:
                sub = f"{base}.{alias.name}"
                found.add(sub if sub in modules else base)
        elif isinstance(node, ast.Call) and _is_import_module(node.func) and node.args:
            arg = node.args[0]
            if isinstance(arg, ast.Constant) and isinstance(arg.value, str):
                found.add(arg.value)
    return (found & modules) - {name}


def _is_import_module(func: ast.expr) -> bool:
    if isinstance(func, ast.Attribute):
        return func.attr == "import_module"
    return isinstance(func, ast.Name) and func.id == "import_module"


def import_graph() -> dict[str, set[str]]:
    """module -> the jaxenvs modules it imports."""
    modules = _modules()
    graph: dict[str, set[str]] = {}
    for name, path in modules.items():
        tree = ast.parse(path.read_text(), str(path))
        graph[name] = _imported(tree, name, path.name == "__init__.py", set(modules))
    return graph


def find_cycle(graph: dict[str, set[str]]) -> list[str] | None:
    """One cycle of ``graph`` as ``[a, b, ..., a]``, or ``None``."""
    done: set[str] = set()
    path: list[str] = []

    def visit(node: str) -> list[str] | None:
        if node in path:
            return [*path[path.index(node) :], node]
        if node in done:
            return None
        path.append(node)
        for nxt in sorted(graph.get(node, ())):
            cycle = visit(nxt)
            if cycle:
                return cycle
        path.pop()
        done.add(node)
        return None

    for start in sorted(graph):
        cycle = visit(start)
        if cycle:
            return cycle
    return None


@pytest.mark.full
def test_the_graph_sees_every_kind_of_import():
    graph = import_graph()
    assert "jaxenvs.registry" in graph["jaxenvs.compat.gymnasium"]  # from jaxenvs import registry
    assert "jaxenvs.render" in graph["jaxenvs.run.video"]  # importlib.import_module("...")
    assert "jaxenvs.render.viewer" in graph["jaxenvs.compat.gymnasium"]  # inside a method
    assert "jaxenvs" in graph["jaxenvs.cli.list_cmd"]  # import jaxenvs
    assert "jaxenvs" not in graph["jaxenvs.compat.gymnasium"]  # only its submodule registry


def test_find_cycle():
    assert find_cycle({"a": {"b"}, "b": {"c"}, "c": set()}) is None
    assert find_cycle({"a": {"b"}, "b": {"c"}, "c": {"a"}}) == ["a", "b", "c", "a"]


def test_no_import_cycle():
    cycle = find_cycle(import_graph())
    assert cycle is None, "import cycle: " + " -> ".join(cycle or [])


#: the env layers (physics, robots, tasks, batching and placement): a user of envs only
ENV_LAYER = (
    "jaxenvs.core",
    "jaxenvs.physics",
    "jaxenvs.core.placement",
    "jaxenvs.core.sharding",
    "jaxenvs.registry",
    "jaxenvs.physics.sim",
    "jaxenvs.physics.cengine",
    "jaxenvs.testing",
)


def reachable(graph: dict[str, set[str]], start: str) -> set[str]:
    """Every module ``start`` imports, directly or through others."""
    seen: set[str] = set()
    todo = [start]
    while todo:
        for nxt in graph.get(todo.pop(), ()):
            if nxt not in seen:
                seen.add(nxt)
                todo.append(nxt)
    return seen


def test_reachable():
    assert reachable({"a": {"b"}, "b": {"c"}, "c": set()}, "a") == {"b", "c"}


def test_env_layer_imports_no_agent():
    graph = import_graph()
    layer = [
        m for m in graph if m in ENV_LAYER or m.startswith(("jaxenvs.tasks", "jaxenvs.robots"))
    ]
    assert "jaxenvs.tasks.cartpole" in layer
    for module in layer:
        agents = sorted(m for m in reachable(graph, module) if m.startswith("jaxenvs.agents"))
        assert not agents, f"{module} imports {', '.join(agents)}"


def test_no_private_jax():
    """No module reads JAX's internals (``jax._src``): public APIs only."""
    readers = sorted(name for name, path in _modules().items() if "jax._src" in path.read_text())
    assert readers == []


#: run in a fresh process: what a process that builds no model imports, then a C-engine env
LAZY_MJX = """
import runpy, sys
import jax, jax.numpy as jnp
import jaxenvs
assert "mujoco.mjx" not in sys.modules, "import jaxenvs imported mujoco.mjx"
jaxenvs.list_envs()
jaxenvs.spec("HexapodWalk-v0")
sys.argv = ["jaxenvs", "--help"]
try:
    runpy.run_module("jaxenvs", run_name="__main__")
except SystemExit as e:
    assert e.code in (0, None), e.code
assert "mujoco.mjx" not in sys.modules, "listing envs or the CLI's help imported mujoco.mjx"
# building a model imports it (its state is an mjx.Data); a reset then works (the
# command-line tests step envs in fresh processes)
benv = jaxenvs.make("CartPole-v0", num_envs=2, physics="c")
assert "mujoco.mjx" in sys.modules
obs = jax.jit(benv.reset)(jax.random.key(0)).obs
assert bool(jnp.all(jnp.isfinite(obs))) and obs.shape == (2, 4), obs.shape
print("ok")
"""


def test_mjx_is_imported_only_when_a_model_is_built():
    done = subprocess.run(
        [sys.executable, "-c", LAZY_MJX], capture_output=True, text=True, timeout=300
    )
    assert done.returncode == 0, done.stderr[-3000:]
    help_end = done.stdout.rstrip().rsplit("\n", 1)[-1]
    assert help_end == "ok", done.stdout[-2000:]
