# last warp call (carry .x9, .evp9; the calls before it carried .x0-.x8: mkdir -p /tmp/parts && cp .xK/* /tmp/parts/):
# reassemble and install warp-lang (ten parts of 15 MB), then say so to the orchestrator
cp .x9/* /tmp/parts/ && (cd /tmp/parts && cat xp00 xp01 xp02 xp03 xp04 xp05 xp06 xp07 xp08 xp09 > warp_lang-1.18.0-py3-none-manylinux_2_28_x86_64.whl && md5sum warp_lang-*.whl && python3 -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --target /tmp/site warp_lang-*.whl) && PYTHONPATH=/tmp/site python3 -c "import warp, mujoco; print('warp', warp.__version__, 'mujoco', mujoco.__version__)" && touch /tmp/warp_ok
cat /tmp/lmjx_gpu/orch.log; uptime
