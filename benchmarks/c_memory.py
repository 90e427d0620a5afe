"""Peak memory of 2,048 randomised walkers under the C engine, cold and warm, per stage.

Each run is a fresh process. It imports ``mujoco.mjx`` and ``jaxenvs`` first: every figure
is the peak RSS (MiB) above that point (``import jaxenvs`` imported mjx in earlier
versions and leaves it to the first ``make`` now, ~57 MiB either way; the row's
``import`` is the process's absolute peak there). Then ``jaxenvs.make("HexapodWalk-v0",
num_envs=N, randomize=True, physics="c")``, the batched reset compiled
(``lower().compile()``) and run, the step (state donated) compiled, 20 steps; the peak is
read after each stage. Cold: an empty JAX compile-cache directory; warm: a second process
on the cache the cold one filled. ``--runs`` of each; a row keeps every run and the median.
The programs are compiled with ``jaxenvs.machine.jit`` (jaxenvs' XLA options, as the
library compiles its own); ``--jax-jit`` also measures them compiled by plain ``jax.jit``
(XLA's defaults), run by run interleaved with the first.

``--tree DIR`` measures another checkout than this one (on the subprocesses'
``PYTHONPATH``); ``--baseline DIR`` a second one the same way, run by run interleaved with
the first so that both see the same machine load:

    git archive HEAD | tar -x -C /tmp/this; git archive BASE | tar -x -C /tmp/base
    # (and the built native engine copied into each)
    python benchmarks/c_memory.py --tree /tmp/this --tree-commit HEAD_SHORT \
        --baseline /tmp/base --baseline-commit BASE_SHORT --json c_memory_cpu2
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path

import results_io

#: each run's first lines: the compile cache, mjx and jaxenvs imported, the peak there
MEMORY_PREAMBLE = """
import json, resource, jax, jax.numpy as jnp
jax.config.update("jax_compilation_cache_dir", {cache!r})
jax.config.update("jax_persistent_cache_min_compile_time_secs", 0)
import contextlib, io
with contextlib.redirect_stdout(io.StringIO()):
    from mujoco import mjx
import jaxenvs
def peak():
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024  # MiB
base = peak()
"""

_RUN = (
    MEMORY_PREAMBLE
    + """
out = {{"import": base}}
benv = jaxenvs.make("HexapodWalk-v0", num_envs={n}, randomize=True, physics="c")
out["make"] = peak() - base
import jaxenvs.machine
reset = {jit}(benv.reset).lower(jax.random.key(0)).compile()
out["reset_compiled"] = peak() - base
s = reset(jax.random.key(0))
jax.block_until_ready(s)
out["reset_ran"] = peak() - base
a = jnp.zeros(({n}, 18))
step = {jit}(benv.step, donate_argnums=0).lower(s, a).compile()
out["step_compiled"] = peak() - base
for _ in range(20):
    s = step(s, a)
jax.block_until_ready(s)
out["steps"] = peak() - base
print(json.dumps(out))
"""
)

STAGES = ("import", "make", "reset_compiled", "reset_ran", "step_compiled", "steps")


def _commit(tree: Path) -> str:
    done = subprocess.run(
        ["git", "-C", str(tree), "rev-parse", "--short", "HEAD"], capture_output=True, text=True
    )
    return done.stdout.strip() or "unknown"


def _run(tree: Path, n: int, cache: str, jit: str) -> dict:
    env = dict(os.environ, PYTHONPATH=str(tree))
    code = _RUN.format(n=n, cache=cache, jit=jit)
    done = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, check=True, env=env
    )
    return json.loads(done.stdout.strip().splitlines()[-1])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--envs", type=int, default=2048)
    parser.add_argument("--runs", type=int, default=3)
    parser.add_argument("--tree", type=Path, help="the checkout to measure (default: this one)")
    parser.add_argument("--tree-commit", help="its commit, if DIR is not a git checkout")
    parser.add_argument("--baseline", type=Path, help="another checkout to measure alike")
    parser.add_argument("--baseline-commit", help="its commit, if DIR is not a git checkout")
    parser.add_argument("--jax-jit", action="store_true", help="also with plain jax.jit")
    parser.add_argument("--json", help=results_io.HELP)
    args = parser.parse_args()
    jits = ["jaxenvs.machine.jit", *(["jax.jit"] if args.jax_jit else [])]
    trees = {"this": (args.tree or Path(__file__).resolve().parents[1]).resolve()}
    if args.baseline:
        trees["baseline"] = args.baseline.resolve()
    runs: dict[tuple[str, str, str], list[dict]] = {}
    for i in range(args.runs):
        for label, tree in trees.items():
            for jit in jits:
                with tempfile.TemporaryDirectory() as cache:
                    for which in ("cold", "warm"):
                        r = _run(tree, args.envs, cache, jit)
                        runs.setdefault((label, jit, which), []).append(r)
                        print(i, label, jit, which, r, flush=True)
    rows = []
    for (label, jit, which), rs in runs.items():
        commit = args.tree_commit if label == "this" else args.baseline_commit
        rows.append(
            {
                "measure": "memory_stages",
                "tree": label,
                "tree_commit": commit or _commit(trees[label]),
                "envs": args.envs,
                "jit": jit,
                "randomize": True,
                "compile_cache": which,
                "runs": rs,
                **{s: statistics.median(r[s] for r in rs) for s in STAGES},
            }
        )
    if args.json:
        title = "C engine: peak memory of randomised walkers by stage, cold and warm"
        results_io.write(args.json, results_io.record(args.json, title, rows, engine="c"))


if __name__ == "__main__":
    main()
