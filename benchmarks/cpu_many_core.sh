#!/usr/bin/env bash
# Many-core CPU figures (the 16-core CPU of a GPU host, JAX_PLATFORMS=cpu), one run:
# both engines beside MuJoCo's C rollout, the walker on one XLA CPU device, and cold
# CartPole PPO under each engine. Writes OUT/*.json and OUT/*.txt (OUT defaults to ./out).
#     bash benchmarks/cpu_many_core.sh /tmp/out
set -uo pipefail
out="${1:-${OUT:-out}}"
mkdir -p "$out"
export JAX_PLATFORMS=cpu PYTHONUNBUFFERED=1
nproc | tee "$out/nproc.txt"
bench() { timeout "$1" python3 -m jaxenvs bench "${@:3}" --json "$out/$2.json" 2>&1 | grep -v '^# round' | tee "$out/$2.txt"; }
bench 200 cpu_cartpole_reacher --tasks CartPole-v0 Reacher-v0 --batches 16384 65536 --modes full --peers --repeats 3
bench 200 cpu_walker --tasks HexapodWalk-v0 --batches 1024 4096 --steps 20 --modes full --peers --repeats 3
XLA_FLAGS=--xla_force_host_platform_device_count=1 \
  bench 100 cpu_walker_one_device --tasks HexapodWalk-v0 --batches 1024 --steps 20 --modes full --physics mjx --repeats 3
for args in "--physics c" "--physics mjx" "--physics mjx --devices 1"; do
  name=$(echo "$args" | tr -d ' -')
  start=$(date +%s.%N)
  timeout 150 python3 -m jaxenvs train CartPole-v0 --algo ppo --no-video --no-compile-cache \
    --quiet $args --out "/tmp/cp_$name" 2>&1 | tee "$out/ppo_cartpole_$name.txt"
  echo "whole command $(python3 -c "import time; print(round(time.time() - $start, 1))") s ($args)" | tee -a "$out/ppo_cartpole_$name.txt"
done
