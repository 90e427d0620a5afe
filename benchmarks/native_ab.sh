#!/usr/bin/env bash
# The native engine built from this checkout's engine.cc against one built from another
# engine.cc (BASE_CC, e.g. `git show COMMIT:jaxenvs/physics/native/engine.cc > base.cc`),
# in alternating bench processes on the CPU: ROUNDS rounds (default 2) of base, then
# this checkout, each `jaxenvs bench --physics c --modes full` over the tasks and batches.
#     bash benchmarks/native_ab.sh BASE_CC NAME [TASK:BATCH[,BATCH...]:STEPS ...]
# e.g. bash benchmarks/native_ab.sh /tmp/base.cc native_ab_cpu2 CartPole-v0:4096:50
# Writes benchmarks/results/NAME.json (every row tagged "build": "base" or "head" and its
# "round"); raw output in $OUT (./out). Both builds use the same compiler and flags
# (setup.py); the checkout's own build is put back at the end.
set -euo pipefail
base_cc=$(realpath "$1")
name=$2
shift 2
plans=("$@")
[ ${#plans[@]} -eq 0 ] && plans=(CartPole-v0:4096,16384:50 Reacher-v0:4096,16384:50)
here="$(cd "$(dirname "$0")/.." && pwd)"
out="$(realpath -m "${OUT:-out}")"
mkdir -p "$out"
export JAX_PLATFORMS=cpu PYTHONUNBUFFERED=1
native="$here/jaxenvs/physics/native"

# build ENGINE_CC DEST: the extension of ENGINE_CC, built as setup.py builds it, to DEST
build() {
  local tmp
  tmp=$(mktemp -d)
  cp "$here/setup.py" "$here/pyproject.toml" "$here/README.md" "$tmp/"
  mkdir -p "$tmp/jaxenvs/physics/native"
  cp "$1" "$tmp/jaxenvs/physics/native/engine.cc"
  (cd "$tmp" && python3 setup.py -q build_ext --inplace >/dev/null)
  cp "$tmp"/jaxenvs/physics/native/_engine*.so "$2"
  rm -rf "$tmp"
}
build "$base_cc" "$out/base.so"
build "$native/engine.cc" "$out/head.so"
so=$(ls "$native"/_engine*.so)
trap 'cp "$out/head.so" "$so"' EXIT

command="bash benchmarks/native_ab.sh BASE_CC $name ${plans[*]}"
for round in $(seq 1 "${ROUNDS:-2}"); do
  for build in base head; do
    cp "$out/$build.so" "$so"
    for plan in "${plans[@]}"; do
      IFS=: read -r task batches steps <<<"$plan"
      raw="$out/${name}_${build}_${round}_${task}.raw.json"
      python3 -m jaxenvs bench --tasks "$task" --batches ${batches//,/ } --steps "$steps" \
        --physics c --modes full --repeats 3 --target-s 0.3 --json "$raw" 2>&1 \
        | grep -v '^# round'
    done
  done
done

python3 - "$out" "$name" "$command" "$here" <<'EOF'
import glob, json, os, sys

sys.path.insert(0, os.path.join(sys.argv[4], "benchmarks"))
import results_io

out, name, command = sys.argv[1:4]
rows = []
for path in sorted(glob.glob(os.path.join(out, f"{name}_*.raw.json"))):
    build, rnd = os.path.basename(path)[len(name) + 1 :].split("_")[:2]
    for row in json.load(open(path))["results"]:
        rows.append(dict(row, build=build, round=int(rnd)))
title = "The native engine of this commit against a base build, alternating processes"
results_io.write(name, results_io.record(name, title, rows, argv=command.split()))
EOF
