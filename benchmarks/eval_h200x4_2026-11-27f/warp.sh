# last warp call (carry .x6, .evp8; the calls before it carried .x0-.x5: mkdir -p /tmp/parts && cp .xK/* /tmp/parts/):
# reassemble and install warp-lang, then say so to the orchestrator
cp .x6/* /tmp/parts/ && (cd /tmp/parts && cat xp0 xp1 xp2 xp3 xp4 xp5 xp6 > warp_lang-1.18.0-py3-none-manylinux_2_28_x86_64.whl && md5sum warp_lang-*.whl && python3 -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --target /tmp/site warp_lang-*.whl) && PYTHONPATH=/tmp/site python3 -c "import warp, mujoco; print('warp', warp.__version__, 'mujoco', mujoco.__version__)" && touch /tmp/warp_ok
cat /tmp/lmjx_gpu/orch.log; uptime
