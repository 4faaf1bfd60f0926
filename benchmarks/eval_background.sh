#!/usr/bin/env bash
# Evaluations that outlive one device call: `launch` starts each run in a process session of
# its own (setsid), so it goes on between calls for as long as the machine is held (up to 30
# minutes; a call's limit is 10); `wait` waits for them and brings back what they hold.
# Run from the repository root on the device machine, after the wheels and the maps are in
# place (benchmarks/gpu_session.sh's set-up, benchmarks/map_parts.sh):
#
#     RUNS="NAME:SIM:TASKS:SCENARIOS:FAILURES:ASMS:CPUS[:K/N[:NICE]] ..." bash benchmarks/eval_background.sh launch
#     WAIT_S=560 bash benchmarks/eval_background.sh wait      # again, call after call
#
# (MAPS: the maps' folder, default /tmp/lmjx_gpu/maps; EXTRA: more `lmjx evaluate` options
# for every run of this launch, e.g. "--seed 7 --when-stuck options"; QUEUE=P, here and for
# calib and recount: run the list P at a time in its order, each next one as soon as one
# ends, instead of all at once)
#
# Without QUEUE, `launch` warns when more runs go at once than the host has cores: their
# decisions slow down, and trials can end at the 600 s planning limit from the load alone
# (the seventeenth session's 147 runs on 64 cores: docs/EVALUATION.md).
#
# Each run is `lmjx evaluate --sim SIM --tasks TASKS --scenarios SCENARIOS --failures
# FAILURES --asms ASMS [--part K/N]` (commas inside a field; '-' leaves it at its default; a
# cell split in N runs, one per K, each with the cell's finished trials carried; NICE: the
# run's scheduling priority, e.g. 19 for runs that should only take idle cores) pinned to the
# cores CPUS (taskset list such as 0-5; '-': any; '@' with QUEUE=P: one core of its own, the
# queue slot's, core FIRST_CORE + slot for slots 0..P-1, so P runs of one core each never
# share one), writing /tmp/lmjx_gpu/NAME/results.json
# after every trial; a results.json carried in .evprev/NAME.json is copied there first, so the
# run resumes it (benchmarks/evprev.py writes those from merged results; benchmarks/evparts.py
# lists unfinished cells as parts holding only their missing trials).  `lmjx evaluate`
# sizes its pools to the cores it is pinned to (lmjx/runtime/cores.py; LMJX_CORES=N, passed on, caps
# them without pinning).  The code runs from a copy made at launch (/tmp/lmjx_repo.<time>, one
# per launch, so a later launch with other code leaves the running ones alone).  `wait` returns
# after WAIT_S seconds or when every run has ended, prints each run's trials and state, and
# packs every run's results.json and the tail of its log into $OUT/ev.tgz (merge with
# benchmarks/eval_acceptance.py --merge).  The machine goes back 30 s after a call ends,
# whatever runs on it: keep `wait` calls coming back to back.  On a machine of several GPUs
# the GPU runs take them in turn (CUDA_VISIBLE_DEVICES), across launches.
#
#     CAL="NAME:SCENARIOS:FIRST:TRIALS:CPUS ..." MAPS=... bash benchmarks/eval_background.sh calib
#
# starts parts of the paper set's calibration the same way (benchmarks/calibrate_tasks.py
# --failures case1 --scenarios S --first F --trials N, writing /tmp/lmjx_gpu/NAME/calib.json);
# merge them with `calibrate_tasks.py --from-runs /tmp/lmjx_gpu/*/calib.json`.
#
#     RECOUNT="NAME:K/N ..." FILES="docs/.../results.json ..." [EXECUTOR=file.py] [MAPS=...] bash benchmarks/eval_background.sh recount
#
# replays those trials in parts (benchmarks/recount_contacts.py --part K/N, writing
# /tmp/lmjx_gpu/NAME/recount.json; merge with its --merge), with the executor of this checkout
# or EXECUTOR (another counting rule's lmjx/sim/realworld.py, e.g. the one the trials ran with).
set -uo pipefail
WORK=/tmp/lmjx_gpu
OUT=${OUT:-$PWD/out/gpu}
mkdir -p "$WORK" "$OUT"

count() {  # trials in a results.json
  python3 -c "import json, sys; print(len(json.load(open(sys.argv[1]))))" "$1" 2>/dev/null || echo 0
}

gpus=$(nvidia-smi -L 2>/dev/null | grep -c ^GPU || true)

next_gpu() {  # the GPUs in turn, across launches: "CUDA_VISIBLE_DEVICES=k" ("" with one GPU)
  [ "$gpus" -gt 1 ] || return 0
  local k=$(( $(cat "$WORK/gpu_next" 2>/dev/null || echo 0) % gpus ))
  echo $(( (k + 1) % gpus )) > "$WORK/gpu_next"
  echo "CUDA_VISIBLE_DEVICES=$k"
}

start() {  # start() NAME DIR PIN ENV ARGS...: one run in a process session of its own
  local name=$1 dir=$2 pin=$3 env=$4; shift 4
  rm -f "$dir.rc"  # a run started again (to resume) is running until it writes it anew
  local job="cd $REPO && export PYTHONPATH=/tmp/site:$REPO PYTHONUNBUFFERED=1 ${LMJX_CORES:+LMJX_CORES=$LMJX_CORES} $env; \
    start=\$(date +%s); $pin python3 $* > $dir.json 2> $dir.err; \
    echo \"rc \$? after \$(( \$(date +%s) - start )) s\" > $dir.rc"
  if [ -n "${QUEUE:-}" ]; then  # run later, QUEUE at a time in the order given (`dispatch`)
    printf '%s\0' "$job" >> "$REPO/queue"
  else
    setsid nohup bash -c "$job" > /dev/null 2>&1 < /dev/null &
  fi
  echo "$name" >> "$WORK/runs"
}

dispatch() {  # this launch's queued runs ($REPO/queue), QUEUE at a time, in a process session of its own
  [ -n "${QUEUE:-}" ] && [ -s "$REPO/queue" ] || return 0
  setsid nohup bash -c "xargs -0 -P $QUEUE --process-slot-var=LMJX_SLOT -n 1 bash -c < $REPO/queue" > "$REPO/queue.log" 2>&1 < /dev/null &
  echo "queued $(tr -cd '\0' < "$REPO/queue" | wc -c) runs, $QUEUE at a time"
}

running() {  # how many runs started so far have not ended (no NAME.rc yet)
  local left=0
  for name in $(sort -u "$WORK/runs"); do [ -f "$WORK/$name.rc" ] || left=$((left + 1)); done
  echo $left
}

crowded() {  # a warning when more runs go at once than the host has cores (their planning times are the load's)
  [ -n "${QUEUE:-}" ] && return 0
  local left cores
  # (nproc alone answers OMP_NUM_THREADS, which the device scripts set to 1: the eighteenth session's
  # warnings said "on 1 cores" on a host of 32)
  left=$(running) cores=$(env -u OMP_NUM_THREADS -u OMP_THREAD_LIMIT nproc)
  [ "$left" -gt "$cores" ] || return 0
  echo "eval_background: warning: $left runs now go at once on $cores cores; their decisions slow down and trials" \
    "can end at the planning limit because of the load alone (QUEUE=P runs this launch P at a time)" >&2
}

if [ -n "${QUEUE:-}" ] && ! [[ "$QUEUE" =~ ^[1-9][0-9]*$ ]]; then
  echo "eval_background: QUEUE must be a whole number of runs at a time (1 or more), not '$QUEUE'" >&2; exit 2
fi
if [ -n "${FIRST_CORE:-}" ] && ! [[ "$FIRST_CORE" =~ ^[0-9]+$ ]]; then
  echo "eval_background: FIRST_CORE must be a core's number (0 or more), not '$FIRST_CORE'" >&2; exit 2
fi

case ${1:-} in
  calib)
    REPO=/tmp/lmjx_repo.$(date +%s%N) && mkdir -p "$REPO" && cp -r lmjx kernels benchmarks pyproject.toml "$REPO/"
    for spec in ${CAL:?CAL names the parts}; do
      IFS=: read -r name scen first n cpus <<< "$spec"
      dir="$WORK/$name"; mkdir -p "$dir"
      pin=""; [ "$cpus" != - ] && pin="taskset -c $cpus"
      args="benchmarks/calibrate_tasks.py --maps ${MAPS:-$WORK/maps} --failures case1 --scenarios $scen --first $first --trials $n --out $dir/calib.json"
      echo "$name: $pin $args"
      start "$name" "$dir" "$pin" "JAX_PLATFORMS=cpu" "$args"
    done
    dispatch
    date -u +"launched %H:%M:%S" ;;
  launch)
    REPO=/tmp/lmjx_repo.$(date +%s%N) && mkdir -p "$REPO" && cp -r lmjx kernels pyproject.toml "$REPO/"
    for spec in ${RUNS:?RUNS names the runs}; do
      IFS=: read -r name sim tasks scen fail asms cpus part nice extra <<< "$spec"
      [ -n "$extra" ] && { echo "eval_background: '$spec' has more than 9 fields" >&2; exit 2; }
      [ "$part" = - ] && part=""
      [ "$nice" = - ] && nice=""
      dir="$WORK/$name"; mkdir -p "$dir"
      [ -f ".evprev/$name.json" ] && [ ! -f "$dir/results.json" ] && cp ".evprev/$name.json" "$dir/results.json"
      args="--sim $sim --tasks $tasks --maps ${MAPS:-$WORK/maps} --out $dir --json ${EXTRA:-}"
      [ "$scen" != - ] && args="$args --scenarios $scen"
      [ "$fail" != - ] && args="$args --failures $fail"
      [ "$asms" != - ] && args="$args --asms $asms"
      [ -n "$part" ] && args="$args --part $part"
      if [ "$cpus" = @ ] && [ -z "${QUEUE:-}" ]; then
        echo "eval_background: '$spec' asks for a queue slot's core ('@'), which needs QUEUE=P" >&2; exit 2
      fi
      pin=""; [ "$cpus" != - ] && pin="taskset -c $cpus"
      [ "$cpus" = @ ] && pin="taskset -c \$(( ${FIRST_CORE:-0} + LMJX_SLOT ))"  # at run time (`dispatch` sets LMJX_SLOT)
      env=""; [ "$sim" = cpu ] && env="JAX_PLATFORMS=cpu"
      if [ "$sim" = gpu ]; then
        env="XLA_PYTHON_CLIENT_PREALLOCATE=false $(next_gpu)"
      fi
      [ -n "$nice" ] && pin="nice -n $nice $pin"
      echo "$name: $env $pin lmjx evaluate $args (resuming $(count "$dir/results.json") trials)"
      start "$name" "$dir" "$pin" "$env" "-m lmjx.cli evaluate $args"
    done
    dispatch
    crowded
    date -u +"launched %H:%M:%S" ;;
  recount)
    REPO=/tmp/lmjx_repo.$(date +%s%N) && mkdir -p "$REPO" && cp -r lmjx kernels benchmarks pyproject.toml "$REPO/"
    if [ -n "${EXECUTOR:-}" ]; then cp "$EXECUTOR" "$REPO/lmjx/sim/realworld.py" || exit 1; fi
    files=""
    for f in ${FILES:?FILES names the results.json files}; do files="$files $(realpath -e "$f")" || exit 1; done
    for spec in ${RECOUNT:?RECOUNT names the parts}; do
      IFS=: read -r name part <<< "$spec"
      dir="$WORK/$name"; mkdir -p "$dir"
      args="benchmarks/recount_contacts.py$files --maps ${MAPS:-$WORK/maps} --part $part --out $dir/recount.json"
      echo "$name: ${EXECUTOR:-the executor of this checkout}: $args"
      start "$name" "$dir" "" "XLA_PYTHON_CLIENT_PREALLOCATE=false $(next_gpu)" "$args"
    done
    dispatch
    date -u +"launched %H:%M:%S" ;;
  wait)
    end=$(( $(date +%s) + ${WAIT_S:-560} ))
    while [ "$(date +%s)" -lt $end ]; do
      [ "$(running)" -eq 0 ] && break
      sleep 10
    done
    date -u +"%H:%M:%S"
    files=()
    for name in $(sort -u "$WORK/runs"); do
      state=$( [ -f "$WORK/$name.rc" ] && cat "$WORK/$name.rc" || echo running )
      echo "$name: $(count "$WORK/$name/results.json") trials$( [ -f "$WORK/$name/calib.json" ] && echo ", calib.json"), $state; $(tail -c 160 "$WORK/$name.err" | tr '\r\n' '  ')"
      tail -c 4000 "$WORK/$name.err" > "$WORK/$name/log.txt" 2>/dev/null
      cp "$WORK/$name.json" "$WORK/$name/summary.json" 2>/dev/null
      files+=("$name")
    done
    tar czf "$OUT/ev.tgz" -C "$WORK" "${files[@]}" && ls -l "$OUT/ev.tgz"
    uptime ;;
  *)
    echo "usage: RUNS=... $0 launch | CAL=... $0 calib | RECOUNT=... FILES=... $0 recount | WAIT_S=... $0 wait" >&2
    exit 2 ;;
esac
