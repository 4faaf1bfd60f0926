# runs in /tmp/rb for the whole session (benchmarks/evaluation_plan_2026-11-28.md, "The nineteenth session"):
# both maps on the GPUs, their digests, the hard set's push counts on the CPU platform (from the carried
# cache when the keys agree), then the hard set's Lazy cells with C MuJoCo: 90 runs of one trial, each
# pinned to a core of its own (QUEUE slots on cores 2..), the longest cells first
cd /tmp/rb
export PYTHONPATH=/tmp/site:/tmp/rb OMP_NUM_THREADS=1 OPENBLAS_NUM_THREADS=1 MKL_NUM_THREADS=1 OUT=/tmp/lmjx_gpu/out
L=/tmp/lmjx_gpu
log() { date -u +"%T $*"; }
sleep 20
while pgrep -f "[b]uild-map" > /dev/null; do sleep 3; done
log "both maps built"; tail -n 3 $L/build1.log $L/build2.log
python3 benchmarks/map_digest.py $L/maps/case1.h5 $L/maps/case2.h5 2>&1 | tail -n 3
ls ~/.cache/lmjx/pushes | wc -l
for spec in case1:1 case1:2 case1:3 case2:1 case2:2 case2:3; do
  IFS=: read -r m s <<< "$spec"
  JAX_PLATFORMS=cpu python3 benchmarks/warm_push_counts.py --map $L/maps/$m.h5 --tasks hard --scenarios $s > $L/warm_hard_${m}_$s.log 2>&1 &
done
wait; log "counts warm"; tail -qn 1 $L/warm_*.log; ls ~/.cache/lmjx/pushes | wc -l
n=$(( $(env -u OMP_NUM_THREADS nproc) - 2 ))
RUNS="$(cat .evpA/lazy.txt)" QUEUE=$n FIRST_CORE=2 LMJX_CORES=1 bash benchmarks/eval_background.sh launch | tail -n 2
log "the hard set's Lazy on the CPU launched, $n at a time"
