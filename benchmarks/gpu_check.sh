#!/usr/bin/env bash
# The GPU figures of the co-design engine in one prepared run on a lent GPU machine (its image has JAX
# with CUDA, optax, scipy, matplotlib, rich; MuJoCo 3.17 and the rest travel as cp312 wheels in .whl/):
#   1. co-design throughput, B = 1024 designs in one program, float64, against 4 designs one at a time;
#   2. the same batch in 256 lanes (a lane takes the next design as its own finishes);
#   3. one iteration phase by phase at B = 256 and 1024.
# Each step has its own time limit, so that what finished comes back; JSON and logs go to $OUT.
#
# Here, once:  echo /.whl/ >> .git/info/exclude, then pip download (--no-deps, --python-version 3.12,
#   manylinux x86_64) mujoco==3.17.0 mujoco-mjx==3.17.0 glfw pyopengl websockets trimesh cma
#   importlib_resources into .whl/.
# Device tool: run(command="bash benchmarks/gpu_check.sh", carry=[".whl"], timeout_s=590); leave
#   MUJOCO_GL unset there (EGL fails at import).
set -uo pipefail
cd "$(dirname "$0")/.."
python3 -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --upgrade --target /tmp/site .whl/*.whl \
    || exit 1
export PYTHONPATH="/tmp/site:$PWD" PYTHONUNBUFFERED=1
OUT="${OUT:-benchmarks/results}"
mkdir -p "$OUT"
nvidia-smi --query-gpu=name,memory.total,driver_version --format=csv | tee "$OUT/gpu.txt"
python3 -c "import jax, mujoco; print(jax.__version__, jax.devices(), mujoco.__version__)" | tee -a "$OUT/gpu.txt"
timeout 300 python3 benchmarks/codesign_throughput.py --batch 1024 --sample 4 --out "$OUT" \
    --name codesign_throughput_gpu 2>&1 | grep -v "  batch" | tee "$OUT/codesign_throughput_gpu.log"
timeout 150 python3 benchmarks/codesign_throughput.py --batch 1024 --lanes 256 --sample 1 --out "$OUT" \
    --name codesign_throughput_gpu_lanes 2>&1 | grep -v "  batch" | tee "$OUT/codesign_throughput_gpu_lanes.log"
timeout 100 python3 benchmarks/ip_phases.py --batch 256 1024 --repeats 3 --out "$OUT" --name ip_phases_gpu 2>&1 \
    | tee "$OUT/ip_phases_gpu.log"
ls -l "$OUT"
