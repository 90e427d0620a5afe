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
train() { # name gpu task seed cores
  local s=$(date +%s.%N)
  CUDA_VISIBLE_DEVICES=$2 XDG_CACHE_HOME=/tmp/cache_$1 taskset -c $5 timeout -s TERM 430 python3 -m jaxenvs train $3 \
    --algo ppo --seed $4 --no-video --no-compile-cache --quiet --out runs/$1 > $OUT/log_$1.txt 2>&1
  echo "$1 whole $(python3 -c "import time; print(round(time.time() - $s, 1))") s" | tee -a $OUT/log_$1.txt
  python3 benchmarks/seeds.py slim runs/$1 >> $OUT/log_$1.txt 2>&1
  (CUDA_VISIBLE_DEVICES=$2 taskset -c $5 timeout 140 python3 benchmarks/seeds.py eval runs/$1 >> $OUT/log_$1.txt 2>&1 || echo "$1 mjx eval failed") &
  (JAX_PLATFORMS=cpu taskset -c $5 timeout 150 python3 benchmarks/seeds.py eval runs/$1 --physics c >> $OUT/log_$1.txt 2>&1 || echo "$1 c eval failed") &
  wait
  echo "$1 done $(python3 -c "import time; print(round(time.time() - $s, 1))") s"
}
gpu=0
chain() { # gpu spec[+spec...]
  local one
  for one in ${2//+/ }; do
    local name=${one%%=*} rest=${one#*=}
    train $name $1 ${rest%%:*} ${rest#*:} $(($1 * 16))-$(($1 * 16 + 15))
  done
}
for specs in "$@"; do
  chain $gpu "$specs" &
  gpu=$((gpu + 1))
done
wait
tar czf $OUT/runs.tgz runs/*/policy.npz runs/*/config.yaml runs/*/summary.json runs/*/progress.csv runs/*/*_eval_*.json 2>/dev/null
ls -la $OUT
