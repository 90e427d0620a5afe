#!/usr/bin/env bash
# Seeds of HexapodJoystickRough-v0, one run per GPU, all at once on one host, every run
# cold and cut at $TRAIN_TIMEOUT s (default 660: a run over the 600 s still ends
# with its figures); each packed (benchmarks/seeds.py slim) and evaluated by
# benchmarks/rough_seeds.py under MJX (its GPU) and MuJoCo C (its 16 cores), within
# $EVAL_TIMEOUT s each (default 300): gpu_host.sh's train_eval. Arguments:
# one NAME=SEED per GPU, in GPU order; CONFIG names the config (default: the shipped one),
# e.g. three seeds on a four-GPU host:
#   bash benchmarks/rough_seeds.sh r0=0 r1=1 r2=2
# The runs land in runs/NAME, their logs and files in $OUT (runs.tgz). Then, here (after
# an eval that failed or timed out there, run it here first:
# `JAX_PLATFORMS=cpu python benchmarks/rough_seeds.py eval runs/r0 --physics c`):
#   python benchmarks/rough_seeds.py table runs/r0 runs/r1 runs/r2 --json NAME --gpu GPU
# Run from the repository root of a GPU host (benchmarks/gpu_host.sh sets it up).
source benchmarks/gpu_host.sh
mkdir -p runs
CONFIG=${CONFIG:-ppo_HexapodJoystickRough-v0.yaml}
TRAIN_TIMEOUT=${TRAIN_TIMEOUT:-660} TRAIN_SIGNAL=INT EVAL_SCRIPT=benchmarks/rough_seeds.py
EVAL_TIMEOUT=${EVAL_TIMEOUT:-300}

gpu=0
for spec in "$@"; do
  train_eval ${spec%%=*} $gpu $((gpu * 16))-$((gpu * 16 + 15)) HexapodJoystickRough-v0 \
    --config "$CONFIG" --seed ${spec#*=} &
  gpu=$((gpu + 1))
done
wait
tar czf $OUT/runs.tgz runs/*/policy.npz runs/*/config.yaml runs/*/summary.json runs/*/progress.csv \
  runs/*/rough_eval_*.json 2>/dev/null
ls -la $OUT
