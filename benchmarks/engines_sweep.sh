#!/usr/bin/env bash
# The physics="auto" sweep: every task under both engines (and mujoco.rollout on our MJCF
# beside them) at 1 to 16,384 envs, in one run; the figures behind the auto rule in
# the tasks' cpu_mjx_from (jaxenvs.physics.resolve_engine) and RESULTS.md's engine tables.
#     bash benchmarks/engines_sweep.sh SUFFIX [TASK...]   e.g. cpu2, cpu16
# writes benchmarks/results/engines_sweep_SUFFIX_<task>.json; raw output in $OUT (./out)
# All tasks share one time budget, SWEEP_BUDGET_S seconds (default 570: the three tasks
# fit one 600-s command); a task still running when it ends is stopped.
# Host devices and threads are jaxenvs's default (cores // 2 devices, both engines'
# batches spread over them; see docs/devices.md).
set -uo pipefail
suffix=$1
shift
tasks=("$@")
[ ${#tasks[@]} -eq 0 ] && tasks=(CartPole-v0 Reacher-v0 HexapodWalk-v0)
out="${OUT:-out}"
here="$(cd "$(dirname "$0")" && pwd)"
mkdir -p "$out"
deadline=$((SECONDS + ${SWEEP_BUDGET_S:-570}))
export JAX_PLATFORMS=cpu PYTHONUNBUFFERED=1
for task in "${tasks[@]}"; do
  steps=50
  [ "$task" = HexapodWalk-v0 ] && steps=5
  name="engines_sweep_${suffix}_$(echo "$task" | tr 'A-Z' 'a-z' | tr -d -)"
  args=(--tasks "$task" --batches 1 16 256 4096 16384 --steps "$steps" --modes full --peers
    --peer-envs 4096 --repeats 3 --target-s 0.3)
  left=$((deadline - SECONDS))
  [ "$left" -le 10 ] && { echo "# budget spent: $task skipped" >&2; continue; }
  timeout "$left" python3 -m jaxenvs bench "${args[@]}" --json "$out/$name.raw.json" 2>&1 \
    | grep -v '^# round' | tee "$out/$name.txt"
  python3 "$here/results_io.py" "$out/$name.raw.json" "$name" \
    "$task under MJX and C at 1-16,384 envs beside mujoco.rollout ($suffix)" \
    "JAX_PLATFORMS=cpu jaxenvs bench ${args[*]}"
done
