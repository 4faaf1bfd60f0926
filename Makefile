# lmjx: two commands do everything on a fresh machine.
#   make run    create .venv, install what running needs (requirements.lock), build the case-2
#               map (reach map + 10,000 sampled edges) on the CPU
#   make test   the same set-up plus the tests' packages (requirements-test.lock: pytest, ruff,
#               torch, pytorch_kinematics, PyBullet), then ruff and the test suite
# The lock files are complete, so pip installs them as they are (--no-deps, --no-compile), then
# the runtime's packages and lmjx are byte-compiled on every core at once (compileall -j 0):
# imports stay fast also where Python writes no bytecode itself (PYTHONDONTWRITEBYTECODE=1).
# The tests' packages are left to Python, which compiles what it imports.
PYTHON ?= python3
VENV ?= .venv
BIN := $(VENV)/bin
PIP := $(BIN)/python -m pip install --quiet --disable-pip-version-check --no-deps --no-compile
RUN_STAMP := $(VENV)/.installed-run
TEST_STAMP := $(VENV)/.installed-test

.PHONY: run test lint bench clean

$(RUN_STAMP): pyproject.toml requirements.lock
	$(PYTHON) -m venv $(VENV)
	$(PIP) -r requirements.lock
	$(PIP) -e .
	$(BIN)/python -m compileall -q -j 0 lmjx kernels > /dev/null
	$(BIN)/python -m compileall -q -j 0 "$$($(BIN)/python -c 'import sysconfig; print(sysconfig.get_paths()["purelib"])')" > /dev/null 2>&1 || true  # (files for a newer Python in a package: left as they are)
	touch $@

$(TEST_STAMP): $(RUN_STAMP) requirements-test.lock
	$(PIP) -r requirements-test.lock
	touch $@

run: $(RUN_STAMP)
	$(BIN)/lmjx build-map --failure case2 --out maps/case2.h5

test: $(TEST_STAMP)
	$(BIN)/ruff check lmjx kernels tests benchmarks examples
	$(BIN)/python -m pytest -q -n 2 --dist loadfile --no-loadscope-reorder --durations=15 tests  # two workers, a file each (the longest first: tests/conftest.py)

lint: $(TEST_STAMP)
	$(BIN)/ruff check lmjx kernels tests benchmarks examples

bench: $(TEST_STAMP)
	$(BIN)/lmjx bench

clean:
	rm -rf $(VENV) .pytest_cache .ruff_cache
