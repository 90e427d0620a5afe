# Sourced by the GPU-host scripts (walker_gpus2.sh, flat_contact.sh, flat_seeds.sh): results go to $OUT
# (default out/); mujoco's wheels are installed from .whl/ (drop that line where they are
# installed), the native engine built, and the host's GPUs and cores listed.
set -u
OUT=${OUT:-out}
mkdir -p "$OUT"
python3 -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --upgrade --target /tmp/site .whl/*.whl || exit 1
export PYTHONPATH=/tmp/site:$PWD
python3 setup.py build_ext --inplace >/dev/null 2>&1 || echo BUILD FAIL
nvidia-smi -L; nproc
