# runs in /tmp/rb for the whole session (benchmarks/evaluation_plan_2026-11-28.md, "The eighteenth session"):
# both maps, the push counts on the GPUs; once warp-lang is in, (B) the hard tunnel's Greedy alone (15 runs),
# then, once all 15 have ended, (C) the paper set with the seventh calibration: Lazy (nice 10), Greedy (nice 0),
# Random (--sim cpu, nice 5): 31 runs on 32 cores
cd /tmp/rb
export PYTHONPATH=/tmp/site:/tmp/rb OMP_NUM_THREADS=1 OPENBLAS_NUM_THREADS=1 MKL_NUM_THREADS=1 OUT=/tmp/lmjx_gpu/out
L=/tmp/lmjx_gpu
log() { date -u +"%T $*"; }
count_counts() {  # count_counts MAP TASKS SCENARIO GPU
  CUDA_VISIBLE_DEVICES=$4 XLA_PYTHON_CLIENT_PREALLOCATE=false python3 benchmarks/warm_push_counts.py --map $L/maps/$1.h5 --tasks $2 --scenarios $3 > $L/warm_$2_$1_$3.log 2>&1
}
ended() {  # ended PREFIX N: all N runs PREFIX_k have their .rc
  local n=0
  for f in $L/$1_*.rc; do [ -f "$f" ] && n=$((n + 1)); done
  [ "$n" -ge "$2" ]
}
sleep 20
while pgrep -f "[b]uild-map" > /dev/null; do sleep 3; done
log "both maps built"; tail -n 3 $L/build1.log $L/build2.log
python3 benchmarks/map_digest.py $L/maps/case1.h5 $L/maps/case2.h5 2>&1 | tail -n 3
k=0
for spec in case2:hard:2 case1:paper:2 case2:paper:2 case1:paper:1 case1:paper:3 case2:paper:1 case2:paper:3; do
  IFS=: read -r m t s <<< "$spec"
  count_counts $m $t $s $((k % 2)) &
  k=$((k + 1))
done
wait; log "counts warm"; tail -qn 1 $L/warm_*.log
while [ ! -f /tmp/warp_ok ]; do sleep 3; done
log "warp in"
RUNS="$(cat .evp9/tunnel.txt)" LMJX_CORES=1 bash benchmarks/eval_background.sh launch | tail -n 1
log "B: the tunnel's Greedy launched, alone"
while ! ended ah22 15; do sleep 5; done
log "B: the tunnel's 15 runs ended"; cat $L/ah22_*.rc | sort | uniq -c
RUNS="$(cat .evp9/lazy.txt)" LMJX_CORES=1 bash benchmarks/eval_background.sh launch | tail -n 1
RUNS="$(cat .evp9/greedy.txt)" LMJX_CORES=1 bash benchmarks/eval_background.sh launch | tail -n 1
RUNS="$(cat .evp9/random.txt)" LMJX_CORES=1 bash benchmarks/eval_background.sh launch | tail -n 2
log "C: the paper set launched"
