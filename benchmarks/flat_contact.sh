#!/usr/bin/env bash
# The flat walker and joystick, seed 0, each with its shipped config as it is (the
# family's elliptic cone, `solver: auto`: Newton on the GPU and under MuJoCo C) and with
# that config's env given `cone: pyramidal` and `solver: cg` (the default until
# 2026-11-28; the recorded runs, made before, added `cone: elliptic` and `solver: auto`
# to the configs instead: the same two models): four runs at once on a 4-GPU host, one GPU and 16 cores each, every
# run cold; each evaluated under MJX (its GPU) and MuJoCo C (its cores) by
# benchmarks/seeds.py; the runs in runs/{wp,we,jp,je}, logs in $OUT. Then, here:
#   python benchmarks/seeds.py table runs/wp runs/we --json ppo_walker_contact_<gpu>
#   python benchmarks/seeds.py table runs/jp runs/je --json ppo_joystick_contact_<gpu>
# Run from the repository root of a 4-GPU host (benchmarks/gpu_host.sh sets it up).
source benchmarks/gpu_host.sh
python3 - <<'PY'
import yaml
from jaxenvs.run.run_config import CONFIGS_DIR
for task, name in (("HexapodWalk-v0", "wp"), ("HexapodJoystick-v0", "jp")):
    cfg = yaml.safe_load(open(CONFIGS_DIR / f"ppo_{task}.yaml"))
    cfg["env"].update(cone="pyramidal", solver="cg")
    yaml.safe_dump(cfg, open(f"/tmp/{name}.yaml", "w"), sort_keys=False)
PY
mkdir -p runs
TRAIN_TIMEOUT=420
train() { # name gpu task config cores
  train_eval $1 $2 $5 $3 --config $4 --seed 0
  mkdir -p $OUT/$1
  cp runs/$1/policy.npz runs/$1/progress.csv runs/$1/summary.json runs/$1/config.yaml runs/$1/*_eval_*.json $OUT/$1/ 2>/dev/null
}
(train wp 0 HexapodWalk-v0 /tmp/wp.yaml 0-15) &
(train we 1 HexapodWalk-v0 ppo_HexapodWalk-v0.yaml 16-31) &
(train jp 2 HexapodJoystick-v0 /tmp/jp.yaml 32-47) &
(train je 3 HexapodJoystick-v0 ppo_HexapodJoystick-v0.yaml 48-63) &
wait
for r in wp we jp je; do tail -1 runs/$r/progress.csv 2>/dev/null | cut -c1-150; done
