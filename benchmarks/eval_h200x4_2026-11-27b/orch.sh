# The orchestrator of the thirteenth session (2026-11-27), as it ran: from /tmp/rb on the device,
# where .evp4/ held this folder's scripts and lists (.evp4/cal.txt = ../calibration_2026-11-27b/cal_parts.txt,
# .evp4/hard.txt = runs_hard.txt, .evp4/paper.txt = runs_paper.txt); its log: orch.log.
# runs in /tmp/rb for the whole session: calibration once the case-1 map is there; the hard set's counts, then its
# runs once warp-lang is in; the calibration's choice applied, the paper set's counts, then its runs
cd /tmp/rb
export PYTHONPATH=/tmp/site:/tmp/rb OMP_NUM_THREADS=1 OPENBLAS_NUM_THREADS=1 MKL_NUM_THREADS=1 OUT=/tmp/lmjx_gpu/out
L=/tmp/lmjx_gpu
log() { date -u +"%T $*"; }
warm() {  # warm TASKS: the push counts of both maps, three scenarios, six processes on the GPUs
  local k=0
  for c in 1 2; do for s in 1 2 3; do
    CUDA_VISIBLE_DEVICES=$((k % 4)) XLA_PYTHON_CLIENT_PREALLOCATE=false python3 benchmarks/warm_push_counts.py --map $L/maps/case$c.h5 --tasks $1 --scenarios $s > $L/warm_$1_$c$s.log 2>&1 &
    k=$((k + 1))
  done; done
  wait; tail -qn 1 $L/warm_$1_*.log
}
sleep 20
while pgrep -f "[f]ailure case1 --edges" > /dev/null; do sleep 3; done
log "case-1 map built"; tail -n 3 $L/build1.log
CAL="$(cat .evp4/cal.txt)" LMJX_CORES=1 bash benchmarks/eval_background.sh calib | tail -n 1
while pgrep -f "[b]uild-map" > /dev/null; do sleep 3; done
log "both maps built"; tail -n 3 $L/build2.log
python3 benchmarks/map_digest.py $L/maps/case1.h5 $L/maps/case2.h5 2>&1 | tail -n 3
warm hard; log "hard counts warm"
while [ ! -f /tmp/warp_ok ]; do sleep 3; done
log "warp in"
RUNS="$(cat .evp4/hard.txt)" LMJX_CORES=1 bash benchmarks/eval_background.sh launch | tail -n 1
while [ "$(ls $L/ca*.rc 2> /dev/null | wc -l)" -lt 180 ]; do sleep 5; done
log "calibration ended"; grep -L "rc 0" $L/ca*.rc
JAX_PLATFORMS=cpu python3 benchmarks/calibrate_tasks.py --from-runs $L/ca*/calib.json --out $L/calibration.json --apply > $L/cal_apply.log 2>&1
tail -n 25 $L/cal_apply.log; cp lmjx/sim/scenarios.py $L/scenarios_applied.py
warm paper; log "paper counts warm"
RUNS="$(cat .evp4/paper.txt)" LMJX_CORES=1 bash benchmarks/eval_background.sh launch | tail -n 1
log "paper runs launched"
