#!/usr/bin/env bash
# Time to quality on two GPUs: the joystick's two-GPU config beside its one-GPU config,
# each run cold, then evaluated on MJX and MuJoCo C (benchmarks/seeds.py); results in $OUT.
# Run from the repository root on a host with 4 GPUs (benchmarks/gpu_host.sh sets it up),
# one wave per call (each fits in ten minutes):
#   bash benchmarks/joystick_gpus2.sh 1   # two-GPU seed 0 beside one-GPU seeds 0 and 1
#   bash benchmarks/joystick_gpus2.sh 2   # two-GPU seeds 1 and 2
source benchmarks/gpu_host.sh
mkdir -p runs
train() { # name gpus seed config cores
  local s=$(date +%s.%N)
  CUDA_VISIBLE_DEVICES=$2 XDG_CACHE_HOME=/tmp/cache_$1 taskset -c $5 python3 -m jaxenvs train HexapodJoystick-v0 --algo ppo \
    --config $4 --seed $3 --no-video --no-compile-cache --quiet --out runs/$1 > $OUT/log_$1.txt 2>&1
  echo "$1 whole $(python3 -c "import time; print(round(time.time() - $s, 1))") s" | tee -a $OUT/log_$1.txt
  tail -2 $OUT/log_$1.txt
}
evalrun() { # name gpu cores
  JAX_PLATFORMS=cpu python3 benchmarks/seeds.py slim runs/$1 >> $OUT/log_$1.txt 2>&1  # not on a GPU the other runs hold
  (CUDA_VISIBLE_DEVICES=$2 taskset -c $3 timeout 140 python3 benchmarks/seeds.py eval runs/$1 >> $OUT/log_$1.txt 2>&1 || echo "$1 mjx eval failed") &
  (JAX_PLATFORMS=cpu taskset -c $3 timeout 150 python3 benchmarks/seeds.py eval runs/$1 --physics c >> $OUT/log_$1.txt 2>&1 || echo "$1 c eval failed") &
  wait
  echo "$1 evaluated"
}
G2=ppo_HexapodJoystick-v0.gpus2.yaml; G1=ppo_HexapodJoystick-v0.yaml
case "${1:-1}" in
  1)
    (train jg2s0 0,1 0 $G2 0-31; evalrun jg2s0 0 0-31) &
    (train jg1s0 2 0 $G1 32-47; evalrun jg1s0 2 32-47) &
    (train jg1s1 3 1 $G1 48-63; evalrun jg1s1 3 48-63) &
    wait ;;
  2)
    (train jg2s1 0,1 1 $G2 0-31; evalrun jg2s1 0 0-31) &
    (train jg2s2 2,3 2 $G2 32-63; evalrun jg2s2 2 32-63) &
    wait ;;
esac
tar czf $OUT/runs_small.tgz runs/*/config.yaml runs/*/summary.json runs/*/progress.csv runs/*/*eval*.json runs/*/policy.npz 2>/dev/null
ls -la $OUT
