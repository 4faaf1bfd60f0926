# runs in /tmp/rb for the whole session (benchmarks/evaluation_plan_2026-11-28.md, "The seventeenth session"):
# both maps, every push count on the GPUs, then, once warp-lang is in, the GPU test of the searched escape and every
# Greedy cell (nice 0) and every Lazy cell (nice 10) of both task sets on the evaluation's seeds
cd /tmp/rb
export PYTHONPATH=/tmp/site:/tmp/rb OMP_NUM_THREADS=1 OPENBLAS_NUM_THREADS=1 MKL_NUM_THREADS=1 OUT=/tmp/lmjx_gpu/out
L=/tmp/lmjx_gpu
log() { date -u +"%T $*"; }
count_counts() {  # count_counts MAP TASKS SCENARIO GPU
  CUDA_VISIBLE_DEVICES=$4 XLA_PYTHON_CLIENT_PREALLOCATE=false python3 benchmarks/warm_push_counts.py --map $L/maps/$1.h5 --tasks $2 --scenarios $3 > $L/warm_$2_$1_$3.log 2>&1
}
sleep 20
while pgrep -f "[b]uild-map" > /dev/null; do sleep 3; done
log "both maps built"; tail -n 3 $L/build1.log $L/build2.log
python3 benchmarks/map_digest.py $L/maps/case1.h5 $L/maps/case2.h5 2>&1 | tail -n 3
k=0
for spec in case2:hard:2 case1:hard:2 case1:paper:2 case1:hard:1 case1:hard:3 case2:hard:1 case2:hard:3 case1:paper:1 case1:paper:3 case2:paper:1 case2:paper:2 case2:paper:3; do
  IFS=: read -r m t s <<< "$spec"
  count_counts $m $t $s $((k % 4)) &
  k=$((k + 1))
done
wait; log "counts warm"; tail -qn 1 $L/warm_*.log
while [ ! -f /tmp/warp_ok ]; do sleep 3; done
log "warp in"
( CUDA_VISIBLE_DEVICES=3 XLA_PYTHON_CLIENT_PREALLOCATE=false timeout 500 python3 -m pytest -q -x -p no:cacheprovider \
    tests/test_planning.py -k "wedged" > $L/gputest.log 2>&1; echo "rc $?" >> $L/gputest.log ) &
RUNS="$(cat .evp8/greedy.txt)" LMJX_CORES=1 bash benchmarks/eval_background.sh launch | tail -n 1
log "greedy launched"
RUNS="$(cat .evp8/lazy.txt)" LMJX_CORES=1 bash benchmarks/eval_background.sh launch | tail -n 1
log "lazy launched"
RUNS="$(cat .evp8/random.txt)" LMJX_CORES=1 bash benchmarks/eval_background.sh launch | tail -n 1
log "random launched"
while ! grep -q "^rc " $L/gputest.log 2> /dev/null; do sleep 3; done
log "gpu test: $(tail -n 2 $L/gputest.log | tr '\n' ' ')"
