# one core's share of the paper set's Lazy and Greedy cells with the present default (--servo robot), CPU
K=$1
cd /tmp/cpu16/repo
export PYTHONPATH=/tmp/cpu16/repo LMJX_CACHE_DIR=/tmp/cpu14/cache JAX_PLATFORMS=cpu LMJX_CORES=1 OMP_NUM_THREADS=1
for spec in case1:greedy case2:greedy case1:lazy case2:lazy; do
  IFS=: read -r f a <<< "$spec"
  date -u +"%T start $f $a $K/2"
  taskset -c $((K-1)) /work/main/.venv/bin/python -m lmjx.cli evaluate --sim cpu --tasks paper --maps /tmp/maps1m --failures $f --asms $a --part $K/2 --out /tmp/cpu16/${f}_${a}_$K > /tmp/cpu16/${f}_${a}_$K.log 2>&1
  date -u +"%T end $f $a $K/2 rc $?"
done
