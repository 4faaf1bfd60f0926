# runs in /tmp/rb for the whole session (benchmarks/evaluation_plan_2026-11-28.md, "The sixteenth session"): the
# tunnel's counts, the servo arm once warp-lang is in (stopped if the GPU test of the servo model fails), the other
# counts meanwhile, the 36 Lazy trials on the CPU (pinned, cores 28-63); when the arm has ended, the rule and, if
# the lever is taken, every Greedy cell of both task sets with it on the evaluation's seeds
cd /tmp/rb
export PYTHONPATH=/tmp/site:/tmp/rb OMP_NUM_THREADS=1 OPENBLAS_NUM_THREADS=1 MKL_NUM_THREADS=1 OUT=/tmp/lmjx_gpu/out
L=/tmp/lmjx_gpu
log() { date -u +"%T $*"; }
count_counts() {  # count_counts MAP TASKS SCENARIO GPU [NICE]
  CUDA_VISIBLE_DEVICES=$4 XLA_PYTHON_CLIENT_PREALLOCATE=false nice -n ${5:-0} python3 benchmarks/warm_push_counts.py --map $L/maps/$1.h5 --tasks $2 --scenarios $3 > $L/warm_$2_$1_$3.log 2>&1
}
sleep 20
while pgrep -f "[f]ailure case2 --edges" > /dev/null; do sleep 3; done
log "case-2 map built"; tail -n 3 $L/build2.log
count_counts case2 hard 2 0; log "tunnel counts warm"; tail -n 1 $L/warm_hard_case2_2.log
while [ ! -f /tmp/warp_ok ]; do sleep 3; done
log "warp in"
( CUDA_VISIBLE_DEVICES=3 XLA_PYTHON_CLIENT_PREALLOCATE=false timeout 500 python3 -m pytest -q -x -p no:cacheprovider \
    tests/test_simulate_gpu.py -k matches_c_mujoco > $L/gputest.log 2>&1; echo "rc $?" >> $L/gputest.log ) &
RUNS="$(cat .evp7/servo.txt)" EXTRA="--seed 7 --trials 30 --servo robot" LMJX_CORES=1 bash benchmarks/eval_background.sh launch | tail -n 1
log "servo arm launched"
while pgrep -f "[b]uild-map" > /dev/null; do sleep 3; done
log "both maps built"; python3 benchmarks/map_digest.py $L/maps/case1.h5 $L/maps/case2.h5 2>&1 | tail -n 3
( k=0
  for spec in case1:hard:1 case1:hard:2 case1:hard:3 case2:hard:1 case2:hard:3 case1:paper:1 case1:paper:2 case1:paper:3 case2:paper:1 case2:paper:2 case2:paper:3; do
    IFS=: read -r m t s <<< "$spec"
    count_counts $m $t $s $((k % 3)) 15 &
    k=$((k + 1)); [ $((k % 6)) -eq 0 ] && wait
  done
  wait; log "GPU counts warm"; tail -qn 1 $L/warm_*.log ) &
# the Lazy runs simulate with C MuJoCo and count on the CPU platform (the counts' cache key names JAX's platform)
cpu=()
for spec in case1:1 case1:2 case1:3 case2:1 case2:2 case2:3; do
  IFS=: read -r m s <<< "$spec"
  JAX_PLATFORMS=cpu taskset -c 28-63 python3 benchmarks/warm_push_counts.py --map $L/maps/$m.h5 --tasks hard --scenarios $s > $L/warmcpu_${m}_${s}.log 2>&1 &
  cpu+=($!)
done
wait "${cpu[@]}"; log "CPU counts warm"; tail -qn 1 $L/warmcpu_*.log
RUNS="$(cat .evp7/lazy.txt)" LMJX_CORES=1 bash benchmarks/eval_background.sh launch | tail -n 1
log "lazy launched"
while ! grep -q "^rc " $L/gputest.log 2> /dev/null; do sleep 3; done
log "gpu test: $(tail -n 2 $L/gputest.log | tr '\n' ' ')"
if ! grep -q "^rc 0" $L/gputest.log; then
  pkill -f "servo robot"; log "GPU test failed: the arm stopped"
  echo "NOT TAKEN (the GPU test of the servo model failed)" > $L/rule.txt; exit 0
fi
while [ "$(ls $L/ts_*.rc 2> /dev/null | wc -l)" -lt 30 ]; do sleep 5; done
log "servo arm ended"
python3 - > $L/rule.txt <<'PY'
import glob, json
recs = [r for f in glob.glob("/tmp/lmjx_gpu/ts_*/results.json") for r in json.load(open(f))]
ok = {r["seed"]: r["success"] for r in recs}
print("servo robot", sum(ok.values()), "of", len(ok), "(baseline, the fourteenth session's rescored arm: 26 of 30)")
print("seeds", " ".join(f"{s}:{'G' if ok[s] else 't'}" for s in sorted(ok)))
print("ends", sorted(r["end"] for r in recs if not r["success"]))
print("TAKE" if len(ok) == 30 and sum(ok.values()) >= 28 else "NOT TAKEN")
PY
cat $L/rule.txt
if grep -q "^TAKE" $L/rule.txt; then
  RUNS="$(cat .evp7/evalg.txt)" EXTRA="--servo robot" LMJX_CORES=1 bash benchmarks/eval_background.sh launch | tail -n 1
  log "evaluation launched"
fi
