# Sourced by the GPU-host scripts (walker_gpus2.sh, flat_contact.sh, flat_seeds.sh,
# rough_seeds.sh): results go to $OUT (default out/); mujoco's wheels are installed from
# .whl/ (drop that line where they are installed), the native engine built, and the host's
# GPUs and cores listed.
# train_eval trains one run on one GPU and evaluates it on both engines: cut by
# $TRAIN_SIGNAL (default TERM; INT lets the run end its chunk and write its files) after
# $TRAIN_TIMEOUT s (default 430), evaluated by $EVAL_SCRIPT (default benchmarks/seeds.py)
# within $EVAL_TIMEOUT s each (default 140 under MJX, 150 under C).
set -u
OUT=${OUT:-out}
mkdir -p "$OUT"
python3 -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --upgrade --target /tmp/site .whl/*.whl || exit 1
export PYTHONPATH=/tmp/site:$PWD
python3 setup.py build_ext --inplace >/dev/null 2>&1 || echo BUILD FAIL
nvidia-smi -L; nproc

train_eval() { # name gpu cores task [jaxenvs train args...]: cold
  local name=$1 gpu=$2 cores=$3 task=$4 eval=${EVAL_SCRIPT:-benchmarks/seeds.py} s
  shift 4
  s=$(date +%s.%N)
  CUDA_VISIBLE_DEVICES=$gpu XDG_CACHE_HOME=/tmp/cache_$name taskset -c $cores timeout -s ${TRAIN_SIGNAL:-TERM} ${TRAIN_TIMEOUT:-430} \
    python3 -m jaxenvs train $task --algo ppo "$@" --no-video --no-compile-cache --quiet --out runs/$name > $OUT/log_$name.txt 2>&1
  echo "$name whole $(python3 -c "import time; print(round(time.time() - $s, 1))") s" | tee -a $OUT/log_$name.txt
  JAX_PLATFORMS=cpu python3 benchmarks/seeds.py slim runs/$name >> $OUT/log_$name.txt 2>&1  # on no GPU: the other runs hold them
  (CUDA_VISIBLE_DEVICES=$gpu taskset -c $cores timeout ${EVAL_TIMEOUT:-140} python3 $eval eval runs/$name >> $OUT/log_$name.txt 2>&1 || echo "$name mjx eval failed") &
  (JAX_PLATFORMS=cpu taskset -c $cores timeout ${EVAL_TIMEOUT:-150} python3 $eval eval runs/$name --physics c >> $OUT/log_$name.txt 2>&1 || echo "$name c eval failed") &
  wait
  echo "$name done $(python3 -c "import time; print(round(time.time() - $s, 1))") s"
}
