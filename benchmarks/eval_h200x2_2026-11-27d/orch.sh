# runs in /tmp/rb for the whole session: both maps (GPU-built, the GPU evaluation's digests), the hard set's push
# counts on the CPU platform, then the hard set's Greedy and Lazy cells with C MuJoCo (--sim cpu, 32 candidates),
# one trial a run, one core a run, QUEUE at a time in the list's order (benchmarks/eval_background.sh)
cd /tmp/rb
export PYTHONPATH=/tmp/site:/tmp/rb OMP_NUM_THREADS=1 OPENBLAS_NUM_THREADS=1 MKL_NUM_THREADS=1 OUT=/tmp/lmjx_gpu/out
L=/tmp/lmjx_gpu
log() { date -u +"%T $*"; }
sleep 20
while pgrep -f "[b]uild-map" > /dev/null; do sleep 3; done
log "both maps built"; tail -qn 3 $L/build1.log $L/build2.log
python3 benchmarks/map_digest.py $L/maps/case1.h5 $L/maps/case2.h5 2>&1 | tail -n 3
for spec in case1:1 case1:2 case1:3 case2:1 case2:2 case2:3; do
  IFS=: read -r m s <<< "$spec"
  JAX_PLATFORMS=cpu python3 benchmarks/warm_push_counts.py --map $L/maps/$m.h5 --tasks hard --scenarios $s > $L/warm_${m}_${s}.log 2>&1 &
done
wait; log "hard counts warm (cpu)"; tail -qn 1 $L/warm_*.log
RUNS="$(cat .evp6/runs.txt)" QUEUE=${QUEUE:-30} LMJX_CORES=1 bash benchmarks/eval_background.sh launch | tail -n 2
log "queue launched"
