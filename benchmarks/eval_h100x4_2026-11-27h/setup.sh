# call 3 (carry .m1, .pc, .evpA; calls 1 and 2 carried .m0 and .m2: mkdir -p /tmp/m0 && cp .m0/* /tmp/m0/, the same for .m2):
# mujoco's wheel reassembled, the wheels installed, the repo's copy, the CPU platform's push counts
# (the development machine's cache) in lmjx's cache folder, both maps building on GPUs 0 and 1, the orchestrator
mkdir -p /tmp/parts /tmp/lmjx_gpu/maps /tmp/rb ~/.cache/lmjx/pushes
W=mujoco-3.17.0-cp312-cp312-manylinux_2_27_x86_64.manylinux_2_28_x86_64.whl
cat /tmp/m0/mj0 .m1/mj1 > /tmp/m0/$W && md5sum /tmp/m0/$W
python3 -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --target /tmp/site /tmp/m0/*.whl .m1/*.whl
cp .pc/*.npy ~/.cache/lmjx/pushes/
cp -r lmjx kernels benchmarks tests pyproject.toml .evpA /tmp/rb/
cd /tmp/rb
for c in 2 1; do
  CUDA_VISIBLE_DEVICES=$((2-c)) XLA_PYTHON_CLIENT_PREALLOCATE=false PYTHONPATH=/tmp/site:/tmp/rb setsid nohup python3 -m lmjx.cli build-map --failure case$c --edges 1000000 --seed 0 --no-shard --out /tmp/lmjx_gpu/maps/case$c.h5 > /tmp/lmjx_gpu/build$c.log 2>&1 < /dev/null &
done
setsid nohup bash .evpA/orch.sh > /tmp/lmjx_gpu/orch.log 2>&1 < /dev/null &
sleep 2; nvidia-smi -L; env -u OMP_NUM_THREADS nproc; free -g | head -2; date -u
