# every later call: wait, bring back the runs and the orchestrator's files
cd /tmp/rb && WAIT_S=${WAIT_S:-540} OUT=$OUT bash benchmarks/eval_background.sh wait > /tmp/lmjx_gpu/wait.txt 2>&1
grep -v "^ca" /tmp/lmjx_gpu/wait.txt | grep -v "rc 0 after" | tail -n 60
echo "ended rc 0: $(grep -c 'rc 0 after' /tmp/lmjx_gpu/wait.txt); arm runs ended: $(ls /tmp/lmjx_gpu/t[br]_*.rc 2>/dev/null | wc -l)"
grep -v "^ca" /tmp/lmjx_gpu/wait.txt | grep "rc 0 after" | awk '{print $1, $2, $6}' | tr '\n' ' ' | tail -c 3000; echo
cd /tmp/lmjx_gpu && tar czf $OUT/extra.tgz orch.log wait.txt rule.txt warm_*.log build*.log 2> /dev/null; tail -n 30 orch.log
nvidia-smi --query-gpu=utilization.gpu,memory.used --format=csv
