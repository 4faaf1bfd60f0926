# every later call: wait, bring back the runs and the orchestrator's files
cd /tmp/rb && while [ ! -f /tmp/lmjx_gpu/runs ]; do sleep 5; done
WAIT_S=${WAIT_S:-540} OUT=$OUT bash benchmarks/eval_background.sh wait > /tmp/lmjx_gpu/wait.txt 2>&1
echo "ended: $(grep -c ' rc ' /tmp/lmjx_gpu/wait.txt); running: $(grep -c ', running;' /tmp/lmjx_gpu/wait.txt); trials: $(grep -o '^[^:]*: [0-9]* trials' /tmp/lmjx_gpu/wait.txt | awk '{s+=$2} END {print s}')"
grep -v "rc 0 after" /tmp/lmjx_gpu/wait.txt | grep -v ": 0 trials, running" | tail -n 25
cd /tmp/lmjx_gpu && tar czf $OUT/extra.tgz orch.log wait.txt rule.txt gputest.log warm_*.log build*.log 2> /dev/null; tail -n 14 orch.log; uptime
