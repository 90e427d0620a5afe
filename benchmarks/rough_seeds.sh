#!/usr/bin/env bash
# Seeds of HexapodJoystickRough-v0, one run per GPU, all at once on one host, every run
# cold and cut at $TRAIN_TIMEOUT s (default 660: a run over the issue's 600 s still ends
# with its figures); each packed (benchmarks/seeds.py slim) and evaluated by
# benchmarks/rough_seeds.py under MJX (its GPU) and MuJoCo C (its 16 cores). Arguments:
# one NAME=SEED per GPU, in GPU order; CONFIG names the config (default: the shipped one),
# e.g. the variant over 8,192 envs on a four-GPU host:
#   CONFIG=ppo_HexapodJoystickRough-v0.wide.yaml bash benchmarks/rough_seeds.sh r0=0 r1=1 r2=2
# The runs land in runs/NAME, their logs and files in $OUT (runs.tgz). Then, here (after
# an eval that failed or timed out there, run it here first:
# `JAX_PLATFORMS=cpu python benchmarks/rough_seeds.py eval runs/r0 --physics c`):
#   python benchmarks/rough_seeds.py table runs/r0 runs/r1 runs/r2 --json NAME --gpu GPU
# Run from the repository root of a GPU host (benchmarks/gpu_host.sh sets it up).
source benchmarks/gpu_host.sh
mkdir -p runs
CONFIG=${CONFIG:-ppo_HexapodJoystickRough-v0.yaml}

rough_run() { # name gpu seed
  local name=$1 gpu=$2 cores=$(($2 * 16))-$(($2 * 16 + 15)) s
  s=$(date +%s.%N)
  CUDA_VISIBLE_DEVICES=$gpu XDG_CACHE_HOME=/tmp/cache_$name taskset -c $cores timeout -s INT -k 20 ${TRAIN_TIMEOUT:-660} \
    python3 -m jaxenvs train --config "$CONFIG" --seed $3 --no-video --no-compile-cache --quiet \
    --out runs/$name > $OUT/log_$name.txt 2>&1
  echo "$name whole $(python3 -c "import time; print(round(time.time() - $s, 1))") s" | tee -a $OUT/log_$name.txt
  JAX_PLATFORMS=cpu taskset -c $cores python3 benchmarks/seeds.py slim runs/$name >> $OUT/log_$name.txt 2>&1
  (CUDA_VISIBLE_DEVICES=$gpu taskset -c $cores timeout 300 python3 benchmarks/rough_seeds.py eval runs/$name \
    >> $OUT/log_$name.txt 2>&1 || echo "$name mjx eval failed") &
  (JAX_PLATFORMS=cpu taskset -c $cores timeout 300 python3 benchmarks/rough_seeds.py eval runs/$name --physics c \
    >> $OUT/log_$name.txt 2>&1 || echo "$name c eval failed") &
  wait
  echo "$name done $(python3 -c "import time; print(round(time.time() - $s, 1))") s"
}

gpu=0
for spec in "$@"; do
  rough_run ${spec%%=*} $gpu ${spec#*=} &
  gpu=$((gpu + 1))
done
wait
tar czf $OUT/runs.tgz runs/*/policy.npz runs/*/config.yaml runs/*/summary.json runs/*/progress.csv \
  runs/*/rough_eval_*.json 2>/dev/null
ls -la $OUT
