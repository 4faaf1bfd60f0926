# call 2 (carry .whl2, .evp7; call 1 carried .whl1: mkdir -p /tmp/whl1 && cp .whl1/* /tmp/whl1/): wheels, the repo's
# copy, both maps building on GPUs 0 and 1, the orchestrator
mkdir -p /tmp/parts /tmp/lmjx_gpu/maps /tmp/rb
python3 -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --target /tmp/site .whl2/*.whl /tmp/whl1/*.whl
cp -r lmjx kernels benchmarks tests pyproject.toml .evp7 /tmp/rb/
cd /tmp/rb
for c in 2 1; do
  CUDA_VISIBLE_DEVICES=$((2-c)) XLA_PYTHON_CLIENT_PREALLOCATE=false PYTHONPATH=/tmp/site:/tmp/rb setsid nohup python3 -m lmjx.cli build-map --failure case$c --edges 1000000 --seed 0 --no-shard --out /tmp/lmjx_gpu/maps/case$c.h5 > /tmp/lmjx_gpu/build$c.log 2>&1 < /dev/null &
done
setsid nohup bash .evp7/orch.sh > /tmp/lmjx_gpu/orch.log 2>&1 < /dev/null &
sleep 2; nvidia-smi -L; nproc; free -g | head -2; date -u
