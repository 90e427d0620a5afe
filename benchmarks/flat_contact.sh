#!/usr/bin/env bash
# The flat walker and joystick, seed 0, each with its shipped config (pyramidal cone, CG)
# and with that config's env given `cone: elliptic` and `solver: auto` (Newton on the GPU
# and under MuJoCo C): four runs at once on a 4-GPU host, one GPU and 16 cores each, every
# run cold; each evaluated under MJX (its GPU) and MuJoCo C (its cores) by
# benchmarks/seeds.py; the runs in runs/{wp,we,jp,je}, logs in $OUT. Then, here:
#   python benchmarks/seeds.py table runs/wp runs/we --json ppo_walker_contact_<gpu>
#   python benchmarks/seeds.py table runs/jp runs/je --json ppo_joystick_contact_<gpu>
# Run from the repository root of a 4-GPU host (benchmarks/gpu_host.sh sets it up).
source benchmarks/gpu_host.sh
python3 - <<'PY'
import yaml
from jaxenvs.run.run_config import CONFIGS_DIR
for task, name in (("HexapodWalk-v0", "we"), ("HexapodJoystick-v0", "je")):
    cfg = yaml.safe_load(open(CONFIGS_DIR / f"ppo_{task}.yaml"))
    cfg["env"].update(cone="elliptic", solver="auto")
    yaml.safe_dump(cfg, open(f"/tmp/{name}.yaml", "w"), sort_keys=False)
PY
mkdir -p runs
train() { # name gpu task config cores
  local s=$(date +%s.%N)
  CUDA_VISIBLE_DEVICES=$2 XDG_CACHE_HOME=/tmp/cache_$1 taskset -c $5 timeout -s TERM 420 python3 -m jaxenvs train $3 \
    --algo ppo --config $4 --seed 0 --no-video --no-compile-cache --quiet --out runs/$1 > $OUT/log_$1.txt 2>&1
  echo "$1 whole $(python3 -c "import time; print(round(time.time() - $s, 1))") s" | tee -a $OUT/log_$1.txt
  python3 benchmarks/seeds.py slim runs/$1 >> $OUT/log_$1.txt 2>&1
  (CUDA_VISIBLE_DEVICES=$2 taskset -c $5 timeout 140 python3 benchmarks/seeds.py eval runs/$1 >> $OUT/log_$1.txt 2>&1 || echo "$1 mjx eval failed") &
  (JAX_PLATFORMS=cpu taskset -c $5 timeout 150 python3 benchmarks/seeds.py eval runs/$1 --physics c >> $OUT/log_$1.txt 2>&1 || echo "$1 c eval failed") &
  wait
  mkdir -p $OUT/$1
  cp runs/$1/policy.npz runs/$1/progress.csv runs/$1/summary.json runs/$1/config.yaml runs/$1/*_eval_*.json $OUT/$1/ 2>/dev/null
  echo "$1 done $(python3 -c "import time; print(round(time.time() - $s, 1))") s"
}
(train wp 0 HexapodWalk-v0 ppo_HexapodWalk-v0.yaml 0-15) &
(train we 1 HexapodWalk-v0 /tmp/we.yaml 16-31) &
(train jp 2 HexapodJoystick-v0 ppo_HexapodJoystick-v0.yaml 32-47) &
(train je 3 HexapodJoystick-v0 /tmp/je.yaml 48-63) &
wait
for r in wp we jp je; do tail -1 runs/$r/progress.csv 2>/dev/null | cut -c1-150; done
