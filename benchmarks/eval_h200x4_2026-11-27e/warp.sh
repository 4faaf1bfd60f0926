# last warp call (carry .w5, .evp7; calls before it carried .w0-.w4: cp .wN/* /tmp/parts/): reassemble and
# install warp-lang, then say so to the orchestrator
cp .w5/* /tmp/parts/ && (cd /tmp/parts && cat w00 w01 w02 w03 w04 w05 > warp_lang-1.18.0-py3-none-manylinux_2_28_x86_64.whl && md5sum warp_lang-*.whl && python3 -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --target /tmp/site warp_lang-*.whl) && PYTHONPATH=/tmp/site python3 -c "import warp, mujoco; print('warp', warp.__version__, 'mujoco', mujoco.__version__)" && touch /tmp/warp_ok
cat /tmp/lmjx_gpu/orch.log; uptime
