#!/usr/bin/env bash
# Many-core CPU figures (the 16-core CPU of a GPU host, JAX_PLATFORMS=cpu), one run:
# both engines beside MuJoCo's C rollout, the walker on one XLA CPU device, and cold
# CartPole PPO under each engine. Writes the bench figures as result files
# (benchmarks/results/engines_cpu16_*.json) and the raw output to OUT (default ./out).
#     bash benchmarks/cpu_many_core.sh /tmp/out
set -uo pipefail
out="${1:-${OUT:-out}}"
here="$(cd "$(dirname "$0")" && pwd)"
mkdir -p "$out"
export JAX_PLATFORMS=cpu PYTHONUNBUFFERED=1
nproc | tee "$out/nproc.txt"
# bench SECONDS NAME TITLE ARGS...: one jaxenvs bench run, kept as results/NAME.json
bench() {
  local limit=$1 name=$2 title=$3
  shift 3
  timeout "$limit" python3 -m jaxenvs bench "$@" --json "$out/$name.raw.json" 2>&1 \
    | grep -v '^# round' | tee "$out/$name.txt"
  python3 "$here/results_io.py" "$out/$name.raw.json" "$name" "$title" \
    "JAX_PLATFORMS=cpu ${XLA_FLAGS:+XLA_FLAGS=$XLA_FLAGS }jaxenvs bench $*"
}
bench 200 engines_cpu16_cartpole_reacher \
  "CartPole-v0 and Reacher-v0 under MJX and C beside mujoco.rollout, 16 CPU cores" \
  --tasks CartPole-v0 Reacher-v0 --batches 16384 65536 --modes full --peers --repeats 3
bench 200 engines_cpu16_walker "HexapodWalk-v0 under MJX and C beside mujoco.rollout, 16 CPU cores" \
  --tasks HexapodWalk-v0 --batches 1024 4096 --steps 20 --modes full --peers --repeats 3
XLA_FLAGS=--xla_force_host_platform_device_count=1 \
  bench 100 engines_cpu16_walker_mjx_one_device \
  "HexapodWalk-v0 under MJX on one XLA CPU device, 16 CPU cores" \
  --tasks HexapodWalk-v0 --batches 1024 --steps 20 --modes full --physics mjx --repeats 3
# cold PPO: whole-command times to $out/ppo_cartpole_*.txt (entered by hand into
# results/ppo_cartpole_cold_cpu16_engines.json)
for args in "--physics c" "--physics mjx" "--physics mjx --devices 1"; do
  name=$(echo "$args" | tr -d ' -')
  start=$(date +%s.%N)
  timeout 150 python3 -m jaxenvs train CartPole-v0 --algo ppo --no-video --no-compile-cache \
    --quiet $args --out "/tmp/cp_$name" 2>&1 | tee "$out/ppo_cartpole_$name.txt"
  echo "whole command $(python3 -c "import time; print(round(time.time() - $start, 1))") s ($args)" | tee -a "$out/ppo_cartpole_$name.txt"
done
