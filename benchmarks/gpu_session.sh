#!/usr/bin/env bash
# One device-machine session: install the carried wheels, check the kernels on the GPU
# against C MuJoCo, then time them.  Run from the repository root on the device machine:
#     bash benchmarks/gpu_session.sh [smoke] [tests] [variants] [bench] [maps] [locks]
# (no argument: all; the issue-9 steps: maps100k planner gputests evalgpu; issues 10 and 11:
# warm100k edges5m shard5m speedup5m shardscale threads5m decision uratlas; issue 18: maps2026 agree2026 (or agreedec); issue 19:
# issue19, evmap (once per carried map), evprev (results of an earlier machine), eval19 (again to continue); planner, gputests, evalgpu and decision need
# warp-lang installed in /tmp/site from its parts, see ../shared/tools/warp-parts and docs/DETAILS.md: five of 31 MiB since the tree is 27 MiB).  Everything
# printed also goes to $OUT/session.log; bench.json and the
# lock search (lock_j6j7.json/.png) land in $OUT too (default ./out/gpu).  The wheels come
# from  ../shared/tools/gpu-wheels .whl glfw pyopengl websockets  (carry .whl), with isal's cp312
# wheel beside them (pip download --no-deps --python-version 3.12 --only-binary=:all: -d .whl isal); 'maps'
# compares with CPU maps carried in out/cpu_maps.
set -uo pipefail
OUT=${OUT:-$PWD/out/gpu}
WORK=/tmp/lmjx_gpu
mkdir -p "$OUT" "$WORK/maps"
exec > >(tee -a "$OUT/session.log") 2>&1
[ -d /tmp/site/mujoco ] || python3 -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --upgrade \
  --target /tmp/site .whl/*.whl || { echo "wheel install failed"; exit 1; }
export PYTHONPATH=/tmp/site:$PWD PYTHONUNBUFFERED=1
# Compiled kernels are kept in ~/.cache/lmjx by every lmjx command (lmjx/runtime/cache.py); a Warp
# kernel cache brought along in .wcache/warpcache.tgz spares compiling MuJoCo Warp's kernels.
mkdir -p ~/.cache/lmjx && { [ -f .wcache/warpcache.tgz ] && tar xzf .wcache/warpcache.tgz -C ~/.cache/lmjx || true; }
steps=${*:-smoke tests variants bench maps locks}
date -u
nvidia-smi --query-gpu=name,memory.total,driver_version,clocks.max.sm --format=csv
python3 -c "import sys, jax, mujoco; print(sys.version.split()[0], 'jax', jax.__version__, jax.devices(), 'mujoco', mujoco.__version__)"

for step in $steps; do
  echo "=== $step"
  case $step in
    timing)
      timeout 300 python3 benchmarks/map_timing.py none case2 ;;
    smoke)
      JAX_PLATFORMS=cuda timeout 300 python3 -m lmjx.cli reach --failure none --cell 0.1 --json ;;
    tests)
      # The kernels on the GPU against C MuJoCo / pytorch_kinematics (float32 on the device).
      JAX_PLATFORMS=cuda timeout 400 python3 -m pytest -q -x -p no:cacheprovider \
        tests/test_kinematics.py tests/test_ik.py 2>&1 | tail -15 ;;
    variants)
      timeout 400 python3 benchmarks/ik_variants.py --sizes 1048576 --failures none ;;
    bench)
      timeout 500 python3 -m lmjx.cli bench --out "$OUT/bench.json" ;;
    maps)
      for f in none case1 case2; do
        timeout 300 python3 -m lmjx.cli reach --failure $f --out "$WORK/$f.h5" --json 2> "$WORK/reach_$f.err"
        tail -2 "$WORK/reach_$f.err"
      done
      python3 benchmarks/compare_maps.py out/cpu_maps "$WORK" ;;
    edges)
      timeout 300 python3 -m lmjx.cli build-map --failure case2 --edges 10000 --out "$WORK/case2_10k.h5" --json \
        2> "$WORK/edges10k.err"
      python3 benchmarks/compare_edges.py out/cpu_maps/case2_10k.h5 "$WORK/case2_10k.h5"
      timeout 300 python3 -m lmjx.cli build-map --failure case2 --out "$WORK/case2_100k.h5" --json 2> "$WORK/edges100k.err"
      tail -3 "$WORK/edges100k.err" ;;
    locks1)
      timeout 300 python3 -m lmjx.cli lock-search --joints J3,J5 --base J7=0.785398 --grid 7 --out "$OUT/lock_j3j5.json" \
        --png "$OUT/lock_j3j5.png" | tail -3 ;;
    maps100k)
      # The evaluation's maps (100,000 edges each), built here; case2 twice: the second run finds
      # every program in the compilation cache (~/.cache/lmjx).
      rm -rf ~/.cache/lmjx/jax
      for f in case2 case2 case1; do
        /usr/bin/time -f "build-map $f: %e s wall" timeout 300 python3 -m lmjx.cli build-map --failure $f \
          --out "$WORK/maps/$f.h5" --json > "$OUT/build_$f.json" 2> "$WORK/build.err"; tail -1 "$WORK/build.err"
      done ;;
    planner)
      # Greedy scoring: MuJoCo Warp against C MuJoCo on all host cores, 256/1024/4096 candidates;
      # then the agreement of their choices over some 200 Greedy decisions.
      timeout 580 python3 -m lmjx.cli bench --sections planner,agreement --planner-map "$WORK/maps/case2.h5" \
        --maps "$WORK/maps" --out "$OUT/bench_planner.json" ;;
    plan)
      for asm in greedy lazy; do
        timeout 300 python3 -m lmjx.cli plan --map "$WORK/maps/case2.h5" --scenario 3 --asm $asm --json \
          > "$OUT/plan_$asm.json" 2> "$WORK/plan.err"; tail -2 "$WORK/plan.err"
        python3 -c "import json; d = json.load(open('$OUT/plan_$asm.json')); print({k: d[k] for k in ('simulator', 'candidates', 'success', 'actions', 'planning_s')})"
      done ;;
    gputests)
      # The GPU simulator's tests on the GPU, the 200-decision agreement among them.
      LMJX_TEST_MAPS="$WORK/maps" LMJX_TEST_REPORT="$OUT/agreement.json" timeout 580 python3 -m pytest -q -x \
        -p no:cacheprovider tests/test_simulate_gpu.py 2>&1 | tail -5 ;;
    evmap)
      # An evaluation map carried in .evm1 or .evm2 (one per call: the carry limit), kept in /tmp.
      mkdir -p "$WORK/maps"; cp .evm*/*.h5 "$WORK/maps/" && ls -la "$WORK/maps" ;;
    contacts19)
      # Issue 19's transit contacts on the host's cores (C MuJoCo, Random, no GPU): the rules
      # as they are against two variants, 5 hard-set trials of 4 cells each, in background
      # processes (CONTACT_TRIALS per cell, default 5); raw lines in $OUT/contacts_<variant>.jsonl.
      for v in base lt ltns; do
        case $v in base) opt="" ;; lt) opt="--leave-tolerance 0.0002" ;; ltns) opt="--leave-tolerance 0.0002 --near-speed 0.1" ;; esac
        for cell in case1:1 case1:3 case2:1 case2:3; do
          sc=${cell#*:}; trials=""
          for i in $(seq 0 $(( ${CONTACT_TRIALS:-5} - 1 ))); do trials="$trials $cell:$(( sc * 1000 + i )):random:hard"; done
          ( JAX_PLATFORMS=cpu timeout ${CONTACT_S:-540} python3 benchmarks/transit_contacts.py "$WORK/maps" \
              "$OUT/contacts_$v.jsonl" $opt $trials >> "$WORK/contacts_$v.log" 2>&1 ) &
          cpids="${cpids:-} $!"
        done
      done ;;
    contactswait)
      wait ${cpids:-}; for v in base lt ltns; do
        python3 -c "import json; r=[json.loads(l) for l in open('$OUT/contacts_$v.jsonl')]; print('$v', len(r), 'actions,', sum(bool(x['contacts']) for x in r), 'touched')"
      done ;;
    evprev)
      # Continue an evaluation begun on an earlier machine: the results.json files carried in
      # .evprev/ev_<sim>_<tasks>/ seed the run directories (lmjx evaluate skips recorded trials).
      for d in .evprev/ev_*; do
        [ -f "$d/results.json" ] || continue
        mkdir -p "$WORK/$(basename "$d")"; cp "$d/results.json" "$WORK/$(basename "$d")/"
        python3 -c "import json; print('$d', len(json.load(open('$d/results.json'))), 'trials carried')"
      done ;;
    eval19)
      # Issue 19: both task sets, on the GPU (MuJoCo Warp, 1,024 candidates) and on the 16 host
      # cores (C MuJoCo, 32 candidates, JAX on the CPU) at once; resumable, each run stops
      # before the call's limit (EVAL_S seconds from now) and the next call continues it.
      # GPU_TASKS / CPU_TASKS choose each simulator's task sets (default: TASKS, paper hard).
      deadline=$(( $(date +%s) + ${EVAL_S:-560} ))
      run_eval() {  # sim tasks [scenario [failure]: only them, in ev_<sim>_<tasks>_s<scenario>[_<failure>]]
        left=$(( deadline - $(date +%s) )); [ $left -gt 20 ] || return 0
        n="ev_$1_$2${3:+_s$3}${4:+_$4}"
        /usr/bin/time -f "eval $n: %e s wall" timeout $left python3 -m lmjx.cli evaluate --sim $1 --tasks $2 \
          ${3:+--scenarios $3} ${4:+--failures $4} ${ASMS:+--asms $ASMS} --maps "$WORK/maps" --out "$WORK/$n" --json > "$WORK/$n.json" \
          2> "$WORK/$n.err"
        tail -2 "$WORK/$n.err"; mkdir -p "$OUT/$n"; cp "$WORK/$n"/* "$OUT/$n/" 2>/dev/null
        cp "$WORK/$n.json" "$OUT/$n/summary.json" 2>/dev/null
      }
      # GPU_PAR=1: each GPU task set in a process of its own, at once (they share the GPU);
      # GPU_SPLIT=1: each scenario of each GPU task set in a process of its own (results in
      # ev_gpu_<tasks>_s<n>: merge them with benchmarks/eval_acceptance.py --merge)
      pids=""
      if [ -n "${GPU_SPLIT:-}" ]; then
        # SCENARIOS (default 1 2 3) picks the scenarios; SPLIT_FAILURES (e.g. "case1 case2") also
        # gives each failure a process of its own (ev_gpu_<tasks>_s<n>_<failure>)
        for t in ${GPU_TASKS:-${TASKS:-paper hard}}; do for s in ${SCENARIOS:-1 2 3}; do
          for f in ${SPLIT_FAILURES:-""}; do
            ( XLA_PYTHON_CLIENT_PREALLOCATE=false; export XLA_PYTHON_CLIENT_PREALLOCATE; run_eval gpu $t $s $f ) &
            pids="$pids $!"
          done
        done; done
      elif [ -n "${GPU_PAR:-}" ]; then
        for t in ${GPU_TASKS:-${TASKS:-paper hard}}; do
          ( XLA_PYTHON_CLIENT_PREALLOCATE=false; export XLA_PYTHON_CLIENT_PREALLOCATE; run_eval gpu $t ) &
          pids="$pids $!"
        done
      else
        ( XLA_PYTHON_CLIENT_PREALLOCATE=false; export XLA_PYTHON_CLIENT_PREALLOCATE
          for t in ${GPU_TASKS:-${TASKS:-paper hard}}; do run_eval gpu $t; done ) &
        pids=$!
      fi
      [ "${SIMS:-gpu cpu}" = gpu ] || { ( JAX_PLATFORMS=cpu; export JAX_PLATFORMS
        for t in ${CPU_TASKS:-${TASKS:-paper hard}}; do run_eval cpu $t; done ) & pids="$pids $!"; }
      wait $pids  # (a bare wait would also wait for the tee of the log: forever)
      for d in "$OUT"/ev_*; do python3 -c "import json,sys; r=json.load(open('$d/results.json')); print('$d', len(r), 'trials')" 2>/dev/null; done ;;
    evalgpu)
      # The paper's evaluation with the GPU simulator (resumable: run again to continue).
      timeout 580 python3 -m lmjx.cli evaluate --maps "$WORK/maps" --out "$WORK/eval_gpu" --json \
        > "$OUT/eval_gpu.json" 2> "$WORK/eval.err"; tail -3 "$WORK/eval.err"
      cp "$WORK/eval_gpu/results.json" "$OUT/results_gpu.json" ;;
    atlas1)
      # The whole atlas (K = 3, 1,134 maps) on one GPU, compilation included (cold cache).
      JAX_COMPILATION_CACHE_DIR= /usr/bin/time -f "atlas1 wall %e s" timeout 590 python3 -m lmjx.cli atlas --no-shard \
        --out "$WORK/atlas1.h5" --json > "$OUT/atlas1.json" 2> "$WORK/atlas1.err"; tail -2 "$WORK/atlas1.err"
      cat "$OUT/atlas1.json"; cp "$WORK/atlas1.h5" "$OUT/atlas1.h5" ;;
    atlas2)
      # The same atlas with the batch sharded over every local GPU; then compare the files.
      JAX_COMPILATION_CACHE_DIR= /usr/bin/time -f "atlas2 wall %e s" timeout 590 python3 -m lmjx.cli atlas \
        --out "$WORK/atlas2.h5" --json > "$OUT/atlas2.json" 2> "$WORK/atlas2.err"; tail -2 "$WORK/atlas2.err"
      cat "$OUT/atlas2.json"; cp "$WORK/atlas2.h5" "$OUT/atlas2.h5"
      python3 -c "from lmjx.atlas import same_content as s; print('atlas1 vs atlas2 differences:', s('$WORK/atlas1.h5', '$WORK/atlas2.h5'))" ;;
    atlas5)
      # Scaling on a larger atlas: K = 5 (4,900 maps), one GPU and then every local GPU.
      for mode in --no-shard ""; do
        JAX_COMPILATION_CACHE_DIR= timeout 280 python3 -m lmjx.cli atlas --angles 5 $mode --out "$WORK/atlas5$mode.h5" \
          --json 2> /dev/null | tr -d '\n '; echo
      done
      python3 -c "from lmjx.atlas import same_content as s; print('K=5 1 vs all GPUs differences:', s('$WORK/atlas5--no-shard.h5', '$WORK/atlas5.h5'))" ;;
    warm100k)
      # Issue 9 "compile once": build-map case2 (100,000 edges) with an empty cache, then again.
      rm -rf ~/.cache/lmjx/jax ~/.cache/lmjx/export
      for run in cold warm; do
        /usr/bin/time -f "build-map case2 100k ($run cache): %e s wall" timeout 300 python3 -m lmjx.cli build-map \
          --failure case2 --out "$WORK/maps/case2.h5" --json > "$OUT/build100k_$run.json" 2> "$WORK/build.err"
        tail -1 "$WORK/build.err"
      done ;;
    edges5m)
      # Issue 10: 5,000,000 edges on one GPU, compilation included; peak host memory of the
      # build's two processes together (benchmarks/tree_rss.py).
      /usr/bin/time -v python3 benchmarks/tree_rss.py -- timeout 400 python3 -m lmjx.cli build-map --failure case2 --edges 5000000 --no-shard \
        --out "$WORK/maps/case2_5M.h5" --json > "$OUT/build5m_1gpu.json" 2> "$WORK/build5m.err"
      grep -aE "preflight|Elapsed|Maximum resident|tree_rss" "$WORK/build5m.err"; cat "$OUT/build5m_1gpu.json" ;;
    profile)
      # Where a streamed build's time goes (1,000,000 edges, one GPU, warm cache).
      /usr/bin/time -v timeout 300 python3 -m lmjx.cli build-map --failure case2 --edges 1000000 --no-shard \
        --out "$WORK/case2_1M.h5" --json > "$OUT/build1m.json" 2> "$WORK/build1m.err"
      grep -aE "Elapsed|Maximum resident" "$WORK/build1m.err"
      python3 -c "import json; e = json.load(open('$OUT/build1m.json'))['edges']; print({k: e[k] for k in e if 'second' in k or k in ('rollout_timing', 'packers')})" ;;
    shard5m)
      # The same on every local GPU: the same datasets, and the speed-up after compilation.
      /usr/bin/time -v python3 benchmarks/tree_rss.py -- timeout 400 python3 -m lmjx.cli build-map --failure case2 --edges 5000000 \
        --out "$WORK/case2_5M_all.h5" --json > "$OUT/build5m_all.json" 2> "$WORK/build5m_all.err"
      grep -aE "Elapsed|Maximum resident|tree_rss" "$WORK/build5m_all.err"; cat "$OUT/build5m_all.json"
      timeout 200 python3 benchmarks/same_map.py "$WORK/maps/case2_5M.h5" "$WORK/case2_5M_all.h5" ;;
    speedup5m)
      # Issue 10: 5,000,000 edges on one GPU, then on every GPU, ${REPEATS:-3} times (the speed-up
      # varies from run to run); the datasets compared once; the speed-ups (benchmarks/speedup.py).
      rm -f "$OUT"/speedup5m_*.json
      for r in $(seq "${REPEATS:-3}"); do
        for mode in --no-shard ""; do
          tag=${mode:+1gpu}; tag=${tag:-all}
          rm -f "$WORK/s5m_$tag.h5"  # (replacing a map frees the old one's blocks: seconds of its own)
          /usr/bin/time -f "run $r $tag: %e s wall, compilation included" python3 benchmarks/tree_rss.py -- timeout 300 \
            python3 -m lmjx.cli build-map --failure case2 --edges 5000000 $mode --out "$WORK/s5m_$tag.h5" --json \
            > "$OUT/speedup5m_${r}_$tag.json" 2> "$WORK/s5m.err"
          grep -aE "tree_rss|wall, compilation" "$WORK/s5m.err"
        done
        [ "$r" = 1 ] && timeout 200 python3 benchmarks/same_map.py "$WORK/s5m_1gpu.h5" "$WORK/s5m_all.h5"
      done
      python3 benchmarks/speedup.py "$OUT"/speedup5m_*.json ;;
    threads5m)
      # Issue 10: where the threads of a 5M build stand (lmjx/runtime/threadprof.py), on 1 GPU, then on all.
      for mode in --no-shard ""; do
        tag=${mode:+_1gpu}
        LMJX_THREAD_PROFILE="$OUT/threads5m${tag:-_all}.json" timeout 300 python3 -m lmjx.cli build-map \
          --failure case2 --edges 5000000 $mode --out "$WORK/t5m.h5" --json > "$OUT/build5m_threads${tag:-_all}.json" \
          2> /dev/null; rm -f "$WORK/t5m.h5"
        python3 -c "import json; d = json.load(open('$OUT/threads5m${tag:-_all}.json'))['groups']; [print(g, v['samples'], v['top'][:3]) for g, v in d.items()]"
      done ;;
    shardscale)
      # Issue 10: the rollout program alone on 1 and on every GPU, and the device-to-host copy rate.
      timeout 300 python3 benchmarks/shard_scaling.py --edges 2000000 --out "$OUT/scaling.json" 2>&1 | tail -3 ;;
    issue19)
      # Issue 19 on the GPU: the scene-clearance kernels against C MuJoCo (tests on the GPU
      # backend), a 100,000-edge case-2 map, one Greedy trial per scenario with 1,024
      # candidates (planning time per decision, the actions' records), the GPU simulator's tests.
      JAX_PLATFORMS=cuda timeout 300 python3 -m pytest -q -x -p no:cacheprovider tests/test_collision.py -k scene \
        2>&1 | tail -3
      [ -f "$WORK/maps/case2.h5" ] || /usr/bin/time -f "build-map case2 100k: %e s wall" timeout 300 python3 -m \
        lmjx.cli build-map --failure case2 --out "$WORK/maps/case2.h5" --json > "$OUT/build_case2.json" \
        2> "$WORK/build.err"; tail -2 "$WORK/build.err"
      for sc in 1 2 3; do
        timeout 300 python3 -m lmjx.cli plan --map "$WORK/maps/case2.h5" --scenario $sc --asm greedy --seed 900 \
          --max-actions 5 --json > "$OUT/plan19_s$sc.json" 2> "$WORK/plan.err"; tail -2 "$WORK/plan.err"
        python3 -c "import json; d = json.load(open('$OUT/plan19_s$sc.json')); print({k: d[k] for k in ('simulator', 'candidates', 'success', 'actions', 'planning_s', 'end')}, [(s['candidates'], s['simulated'], s['planning_s'], s['target_moved_m'], s['transit_hit_fixed']) for s in d['steps']])"
      done
      [ "${GPUTESTS:-1}" = 0 ] || timeout 300 python3 -m pytest -q -x -p no:cacheprovider tests/test_simulate_gpu.py \
        -k "not decides" 2>&1 | tail -3 ;;
    decision)
      # Issue 10: one Greedy decision (GPU simulator, 1,024 candidates) on the 100k and the 5M map.
      [ -f "$WORK/maps/case2.h5" ] || timeout 300 python3 -m lmjx.cli build-map --failure case2 \
        --out "$WORK/maps/case2.h5" --json > /dev/null 2> "$WORK/build.err"
      for m in case2 case2_5M; do
        timeout 280 python3 -m lmjx.cli bench --sections planner --candidates 1024 --repeats 3 \
          --planner-map "$WORK/maps/$m.h5" --out "$OUT/decision_$m.json" 2>&1 | grep -iE "decision|map|error" | head -5
      done ;;
    urmaps)
      # Issue 11: the UR5e's Table I on the GPU (compare with the CPU's in the README).
      for f in none case1 case2; do
        timeout 200 python3 -m lmjx.cli reach --robot ur5e --failure $f --json 2> /dev/null | \
          python3 -c "import json, sys; d = json.load(sys.stdin); print('ur5e $f', d['area_m2'], d['seconds'], 's')"
      done ;;
    uratlas)
      # Issue 11: the UR5e atlas (675 maps, K = 3), compilation included (no cache).
      /usr/bin/time -f "UR5e atlas: %e s wall" timeout 300 python3 -m lmjx.cli --cache-dir off atlas --robot ur5e \
        --out "$WORK/atlas_ur5e.h5" --summary "$OUT/atlas_ur5e.md" --json > "$OUT/atlas_ur5e.json" 2> "$WORK/uratlas.err"
      tail -2 "$WORK/uratlas.err"; cat "$OUT/atlas_ur5e.json"; cp "$WORK/atlas_ur5e.h5" "$OUT/" ;;
    maps2026)
      # Issue 18: the out-of-sample agreement test's maps (100,000 edges, seed 2026: never used
      # before; tests/test_simulate_gpu.py MAP_SEED).
      mkdir -p "$WORK/maps2026"
      for f in case1 case2; do
        /usr/bin/time -f "build-map $f seed 2026: %e s wall" timeout 280 python3 -m lmjx.cli build-map --failure $f \
          --seed 2026 --out "$WORK/maps2026/$f.h5" --json > "$OUT/build2026_$f.json" 2> "$WORK/build.err"
        tail -1 "$WORK/build.err"
      done ;;
    agree2026)
      # Issue 18: the GPU simulator's tests, the out-of-sample agreement among them (thresholds
      # and seeds fixed in the test before this run).
      LMJX_TEST_MAPS="$WORK/maps2026" LMJX_TEST_REPORT="$OUT/agreement2026.json" timeout 580 python3 -m pytest -q \
        -p no:cacheprovider -rA tests/test_simulate_gpu.py 2>&1 | tail -25 ;;
    agreedec)
      # The agreement test's decisions built elsewhere (benchmarks/agreement_run.py MAPS
      # --save-decisions, no GPU needed; DECISIONS: the file, default /tmp/dec/decisions.pkl.gz)
      # measured here: MuJoCo Warp against C MuJoCo on this host's cores.
      timeout 580 python3 benchmarks/agreement_run.py --decisions "${DECISIONS:-/tmp/dec/decisions.pkl.gz}" \
        --out "$OUT/agreement.json" 2>&1 | tail -3 ;;
    locks)
      timeout 500 python3 -m lmjx.cli lock-search --joints J6,J7 --grid 9 --out "$OUT/lock_j6j7.json" \
        --png "$OUT/lock_j6j7.png" | tail -3 ;;
  esac
done
date -u
