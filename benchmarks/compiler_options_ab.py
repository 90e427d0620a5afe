"""XLA's loop emitters (jaxenvs' programs) against its fusion emitters (XLA's default on a
CPU), side by side in one process: compile time and throughput.

Each plan entry ``[task, steps, [batches], [engines]]`` prepares ``jaxenvs bench``'s full
step (:func:`jaxenvs.bench.prepare_ours`) once per batch, engine and variant, the
variants alternating in the order they are prepared: ``loop`` compiles with
:data:`jaxenvs.core.xla.COMPILER_OPTIONS` (what jaxenvs does), ``fusion`` with
``xla_cpu_use_fusion_emitters=True`` (XLA's default). Each prepared program records its
trace and compile times; all are then timed in the same interleaved rounds
(:func:`jaxenvs.bench.time_runners`, 3 rounds of ~0.3 s, medians). The host devices are
JAX's (set ``XLA_FLAGS=--xla_force_host_platform_device_count=N``; one without it).

    JAX_PLATFORMS=cpu python benchmarks/compiler_options_ab.py \\
      '[["CartPole-v0", 50, [4096], ["c", "mjx"]]]' --json NAME
"""

from __future__ import annotations

import argparse
import json
import time
from types import MappingProxyType

import results_io

from jaxenvs import bench
from jaxenvs.core import xla

VARIANTS = {
    "loop": xla.COMPILER_OPTIONS,
    "fusion": MappingProxyType({"xla_cpu_use_fusion_emitters": True}),
}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("plan", help="JSON: [[task, steps, [batches], [engines]], ...]")
    parser.add_argument("--json", help=results_io.HELP)
    parser.add_argument("--description", default="", help="the machine, in words")
    args = parser.parse_args()
    ours = xla.COMPILER_OPTIONS
    if not ours:
        raise SystemExit("this jax compiles jaxenvs with XLA's defaults: nothing to compare")
    runners = []
    order = 0
    for task, steps, batches, engines in json.loads(args.plan):
        for n in batches:
            for physics in engines:
                names = list(VARIANTS)
                for variant in names[order % 2 :] + names[: order % 2]:
                    xla.COMPILER_OPTIONS = VARIANTS[variant]
                    t0 = time.perf_counter()
                    runner = bench.prepare_ours(task, n, "full", steps, physics=physics)
                    runner.variant = variant
                    print(
                        f"# prepared {task} x{n} {physics} {variant} in "
                        f"{time.perf_counter() - t0:.1f} s (compile "
                        f"{runner.info['compile_s']:.2f} s)",
                        flush=True,
                    )
                    runners.append(runner)
                order += 1
    xla.COMPILER_OPTIONS = ours
    results = bench.time_runners(runners, repeats=3, target_s=0.3)
    for r in results:
        print(
            f"{r['task']:16s} {r.get('physics', ''):4s} {r['variant']:7s} {r['num_envs']:>6,d} "
            f"{r['env_steps_per_s']:>12,.0f}  compile {r['compile_s']:.2f} s"
        )
    if args.json:
        variants = {k: dict(v) for k, v in VARIANTS.items()}
        results_io.write_plan_run(
            args.json,
            "XLA's loop emitters against its fusion emitters on a CPU, one process",
            "compiler_options_ab.py",
            args.plan,
            results,
            args.description,
            extra={"machine": bench.machine(), "variants": variants},
        )


if __name__ == "__main__":
    main()
