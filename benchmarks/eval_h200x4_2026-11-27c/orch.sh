# runs in /tmp/rb for the whole session: the tunnel's counts, both arms once warp-lang is in, the other counts
# meanwhile; when both arms have ended, the rule (benchmarks/evaluation_plan_2026-11-28.md) and, if the lever is
# taken, every Greedy cell of both task sets with it on the evaluation's seeds
cd /tmp/rb
export PYTHONPATH=/tmp/site:/tmp/rb OMP_NUM_THREADS=1 OPENBLAS_NUM_THREADS=1 MKL_NUM_THREADS=1 OUT=/tmp/lmjx_gpu/out
L=/tmp/lmjx_gpu
log() { date -u +"%T $*"; }
count_counts() {  # warm_one MAP TASKS SCENARIO GPU
  CUDA_VISIBLE_DEVICES=$4 XLA_PYTHON_CLIENT_PREALLOCATE=false nice -n ${5:-0} python3 benchmarks/warm_push_counts.py --map $L/maps/$1.h5 --tasks $2 --scenarios $3 > $L/warm_$2_$1_$3.log 2>&1
}
sleep 20
while pgrep -f "[f]ailure case2 --edges" > /dev/null; do sleep 3; done
log "case-2 map built"; tail -n 3 $L/build2.log
count_counts case2 hard 2 0; log "tunnel counts warm"; tail -n 1 $L/warm_hard_case2_2.log
while [ ! -f /tmp/warp_ok ]; do sleep 3; done
log "warp in"
RUNS="$(cat .evp5/base.txt)" EXTRA="--seed 7 --trials 30" LMJX_CORES=1 bash benchmarks/eval_background.sh launch | tail -n 1
RUNS="$(cat .evp5/resc.txt)" EXTRA="--seed 7 --trials 30 --rescore-top 8" LMJX_CORES=1 bash benchmarks/eval_background.sh launch | tail -n 1
log "arms launched"
while pgrep -f "[b]uild-map" > /dev/null; do sleep 3; done
log "both maps built"; python3 benchmarks/map_digest.py $L/maps/case1.h5 $L/maps/case2.h5 2>&1 | tail -n 3
k=0
for spec in case1:hard:1 case1:hard:2 case1:hard:3 case2:hard:1 case2:hard:3 case1:paper:1 case1:paper:2 case1:paper:3 case2:paper:1 case2:paper:2 case2:paper:3; do
  IFS=: read -r m t s <<< "$spec"
  count_counts $m $t $s $((k % 4)) 15 &
  k=$((k + 1)); [ $((k % 4)) -eq 0 ] && wait
done
wait; log "all counts warm"; tail -qn 1 $L/warm_*.log
while [ "$(ls $L/tb_*.rc $L/tr_*.rc 2> /dev/null | wc -l)" -lt 60 ]; do sleep 5; done
log "both arms ended"
python3 - > $L/rule.txt <<'PY'
import glob, json
def arm(p):
    recs = [r for f in glob.glob(f"/tmp/lmjx_gpu/{p}_*/results.json") for r in json.load(open(f))]
    return {r["seed"]: r["success"] for r in recs}
b, r = arm("tb"), arm("tr")
print("default", sum(b.values()), "of", len(b), "rescore", sum(r.values()), "of", len(r))
print("seeds", " ".join(f"{s}:{'G' if b.get(s) else 't'}{'G' if r.get(s) else 't'}" for s in sorted(set(b) | set(r))))
print("TAKE" if sum(r.values()) - sum(b.values()) >= 3 else "NOT TAKEN")
PY
cat $L/rule.txt
if grep -q "^TAKE" $L/rule.txt; then
  RUNS="$(cat .evp5/evalg.txt)" EXTRA="--rescore-top 8" LMJX_CORES=1 bash benchmarks/eval_background.sh launch | tail -n 1
  log "evaluation launched"
fi
