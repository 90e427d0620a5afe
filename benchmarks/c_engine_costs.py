"""What the C engine costs beside its throughput: memory under domain randomisation and
the first call.

* ``memory``: peak resident memory above importing ``jaxenvs`` while 2048 walkers
  (``HexapodWalk-v0``, default and randomised params) step 20 times under ``physics="c"``,
  each in a fresh process: once compiling (cold), once loading the programs from JAX's
  persistent cache (warm); and 16 randomised walkers, cold, for the compiler's own share
  of a cold peak. The step is jitted with the state donated, as a training loop's scan
  updates it in place.
* ``first_call``: seconds from ``jaxenvs.make(ID, num_envs=16, physics="c")`` to the end of
  the first jitted reset and step, per task, in a fresh process each.

``import jaxenvs`` leaves ``mujoco.mjx`` to the first ``make`` (~0.9 s, ~57 MiB); both
measures import it before their base, so that they count what they counted when ``import
jaxenvs`` imported it (a process pays it either way).

    python benchmarks/c_engine_costs.py --json c_engine_costs_cpu2
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile

import results_io

import jaxenvs

#: the start of a memory-measuring process (a template: ``{cache}``, the JAX compile-cache
#: directory): ``mujoco.mjx`` and ``jaxenvs`` imported (mjx is imported by the first make,
#: not by jaxenvs: in the base either way), ``peak()`` in MiB, ``base`` the peak there
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

_MEMORY = (
    MEMORY_PREAMBLE
    + """
benv = jaxenvs.make("HexapodWalk-v0", num_envs={n}, randomize={r}, physics="c")
step = jax.jit(benv.step, donate_argnums=0)  # the state updated in place, as in a scan
s = jax.jit(benv.reset)(jax.random.key(0))
for _ in range(20):
    s = step(s, jnp.zeros(({n}, 18)))
jax.block_until_ready(s)
print(json.dumps({{"envs": {n}, "randomize": {r}, "peak_mib_above_import": peak() - base,
                  "path": benv.env.sim.engine.path, "compile_cache": {which!r}}}))
"""
)

_FIRST = """
import contextlib, io, json, time, jax, jax.numpy as jnp
with contextlib.redirect_stdout(io.StringIO()):
    from mujoco import mjx  # not timed: imported by the first make, not by jaxenvs
import jaxenvs
t = time.perf_counter()
benv = jaxenvs.make({task!r}, num_envs=16, physics="c")
env = benv.env
a = jnp.zeros((16, *env.action_shape), jnp.int32 if env.discrete else jnp.float32)
s = jax.jit(benv.step)(jax.jit(benv.reset)(jax.random.key(0)), a)
jax.block_until_ready(s)
print(json.dumps({{"task": {task!r}, "envs": 16, "first_call_s": time.perf_counter() - t}}))
"""


def _run(code: str) -> dict:
    done = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, check=True, timeout=600
    )
    return json.loads(done.stdout.strip().splitlines()[-1])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--envs", type=int, default=2048)
    parser.add_argument("--json", help=results_io.HELP)
    args = parser.parse_args()
    rows = []
    for randomize in (False, True):
        with tempfile.TemporaryDirectory() as cache:
            # cold: the process compiles (XLA's compile is most of its peak); warm: a second
            # process loads the programs from JAX's persistent cache, as a repeat run does
            for which in ("cold", "warm"):
                code = _MEMORY.format(n=args.envs, r=randomize, cache=cache, which=which)
                row = _run(code)
                rows.append({"measure": "memory", **row})
                print(row, flush=True)
    # the compiler's share of a cold peak: the same programs for a batch of 16
    with tempfile.TemporaryDirectory() as cache:
        row = _run(_MEMORY.format(n=16, r=True, cache=cache, which="cold"))
        rows.append({"measure": "memory", **row})
        print(row, flush=True)
    for task in jaxenvs.list_envs():  # every built-in task
        row = _run(_FIRST.format(task=task))
        rows.append({"measure": "first_call", **row})
        print(row, flush=True)
    if args.json:
        title = "C engine: memory of randomised walkers and first calls at 16 envs"
        results_io.write(args.json, results_io.record(args.json, title, rows, engine="c"))


if __name__ == "__main__":
    main()
