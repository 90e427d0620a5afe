#!/usr/bin/env bash
# Time to quality on two GPUs: the walker's two-GPU config (3 seeds, two runs at once on a
# 4-GPU host) beside the one-GPU config (2 seeds), each run cold, then both evaluated on MJX
# and MuJoCo C (benchmarks/seeds.py); results in $OUT. Run from the repository root on a
# host with 4 GPUs (benchmarks/gpu_host.sh sets it up).
source benchmarks/gpu_host.sh
mkdir -p runs
train() { # name gpus seed config cores
  local s=$(date +%s.%N)
  CUDA_VISIBLE_DEVICES=$2 XDG_CACHE_HOME=/tmp/cache_$1 taskset -c $5 python3 -m jaxenvs train HexapodWalk-v0 --algo ppo \
    --config $4 --seed $3 --no-video --quiet --out runs/$1 > $OUT/log_$1.txt 2>&1
  echo "$1 whole $(python3 -c "import time; print(round(time.time() - $s, 1))") s" | tee -a $OUT/log_$1.txt
  tail -2 $OUT/log_$1.txt
}
evalrun() { # name gpu cores
  CUDA_VISIBLE_DEVICES=$2 taskset -c $3 timeout 150 python3 benchmarks/seeds.py eval runs/$1 >> $OUT/log_$1.txt 2>&1 || echo "$1 mjx eval failed"
  JAX_PLATFORMS=cpu taskset -c $3 timeout 150 python3 benchmarks/seeds.py eval runs/$1 --physics c >> $OUT/log_$1.txt 2>&1 || echo "$1 c eval failed"
  echo "$1 evaluated"
}
G2=ppo_HexapodWalk-v0.gpus2.yaml; G1=ppo_HexapodWalk-v0.yaml
(train g2s0 0,1 0 $G2 0-15; evalrun g2s0 0 0-15) &
(train g2s1 2,3 1 $G2 16-31; evalrun g2s1 2 16-31) &
wait
(train g2s2 0,1 2 $G2 0-15; evalrun g2s2 0 0-15) &
(train g1s0 2 0 $G1 16-31; evalrun g1s0 2 16-31) &
(train g1s1 3 1 $G1 32-47; evalrun g1s1 3 32-47) &
wait
python3 benchmarks/seeds.py table runs/g2s0 runs/g2s1 runs/g2s2 --json $OUT/walker_gpus2.json --machine "two GPUs per run" 2>&1 | tail -3
python3 benchmarks/seeds.py table runs/g1s0 runs/g1s1 --json $OUT/walker_gpus1.json --machine "one GPU per run" 2>&1 | tail -3
tar czf $OUT/runs_small.tgz runs/*/config.yaml runs/*/summary.json runs/*/progress.csv runs/*/*_eval_*.json 2>/dev/null
ls -la $OUT
