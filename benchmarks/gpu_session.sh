#!/usr/bin/env bash
# One device-machine session: install the carried wheels, check the kernels on the GPU
# against C MuJoCo, then time them.  Run from the repository root on the device machine:
#     bash benchmarks/gpu_session.sh [tests] [bench] [maps] [locks]
# (no argument: all four).  Results go to $OUT (or ./out/gpu).  The wheels come from
# ../shared/tools/gpu-wheels .whl glfw pyopengl websockets  (carry .whl).
set -uo pipefail
OUT=${OUT:-$PWD/out/gpu}
mkdir -p "$OUT"
python3 -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --upgrade --target /tmp/site .whl/*.whl \
  || { echo "wheel install failed"; exit 1; }
export PYTHONPATH=/tmp/site:$PWD PYTHONUNBUFFERED=1 MUJOCO_GL=egl
# Reuse compiled kernels across the processes of one session.
export JAX_COMPILATION_CACHE_DIR=/tmp/jax_cache JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS=0
steps=${*:-tests variants bench maps locks}
nvidia-smi --query-gpu=name,memory.total,driver_version,clocks.sm,clocks.max.sm --format=csv | tee "$OUT/gpu.txt"
python3 -c "import sys, jax, mujoco; print(sys.version.split()[0], 'jax', jax.__version__, jax.devices(), 'mujoco', mujoco.__version__)" \
  | tee -a "$OUT/gpu.txt"

for step in $steps; do
  case $step in
    tests)
      # The kernels on the GPU against C MuJoCo / pytorch_kinematics (float32 on the device).
      JAX_PLATFORMS=cuda timeout 400 python3 -m pytest -q -x -p no:cacheprovider \
        tests/test_kinematics.py tests/test_ik.py 2>&1 | tail -15 | tee "$OUT/tests.txt" ;;
    bench)
      timeout 500 python3 -m lmjx.cli bench --out "$OUT/bench.json" 2>&1 | tee "$OUT/bench.txt" ;;
    maps)
      for f in none case1 case2; do
        timeout 300 python3 -m lmjx.cli reach --failure $f --out "$OUT/$f.h5" --png "$OUT/$f.png" --json \
          > "$OUT/reach_$f.json" 2> "$OUT/reach_$f.err"; tail -3 "$OUT/reach_$f.err"; cat "$OUT/reach_$f.json"
      done
      python3 benchmarks/compare_maps.py out/cpu_maps "$OUT" 2>&1 | tee "$OUT/compare.txt" ;;
    smoke)
      JAX_PLATFORMS=cuda timeout 300 python3 -m lmjx.cli reach --failure none --cell 0.1 --json 2>&1 | tail -20 ;;
    variants)
      timeout 400 python3 benchmarks/ik_variants.py --sizes 1048576 --failures none 2>&1 | tee "$OUT/variants.txt" ;;
    locks)
      timeout 500 python3 -m lmjx.cli lock-search --joints J6,J7 --grid 15 --out "$OUT/lock_j6j7.json" \
        --png "$OUT/lock_j6j7.png" 2>&1 | tail -3 | tee "$OUT/locks.txt" ;;
  esac
done
