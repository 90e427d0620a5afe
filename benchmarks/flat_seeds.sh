#!/usr/bin/env bash
# Seeds of the flat hexapod tasks with their shipped configs, one run per GPU, all at once
# on one host, every run cold; each evaluated under MJX (its GPU) and MuJoCo C (its 16
# cores) by benchmarks/seeds.py. Arguments: one NAME=TASK:SEED per GPU, in GPU order (or
# several joined by "+", run one after the other on that GPU), e.g.
#   bash benchmarks/flat_seeds.sh j2=HexapodJoystick-v0:2 w0=HexapodWalk-v0:0+w1=HexapodWalk-v0:1
# The runs land in runs/NAME, their logs, evals and progress in $OUT (runs.tgz). Then, here:
#   python benchmarks/seeds.py table runs/w0 runs/w1 runs/w2 --json ppo_walker_waypoints_<gpu>
# Run from the repository root of a GPU host (benchmarks/gpu_host.sh sets it up).
source benchmarks/gpu_host.sh
mkdir -p runs
gpu=0
chain() { # gpu spec[+spec...]
  local one
  for one in ${2//+/ }; do
    local name=${one%%=*} rest=${one#*=}
    train_eval $name $1 $(($1 * 16))-$(($1 * 16 + 15)) ${rest%%:*} --seed ${rest#*:}
  done
}
for specs in "$@"; do
  chain $gpu "$specs" &
  gpu=$((gpu + 1))
done
wait
tar czf $OUT/runs.tgz runs/*/policy.npz runs/*/config.yaml runs/*/summary.json runs/*/progress.csv runs/*/*_eval_*.json 2>/dev/null
ls -la $OUT
