# lmjx: two commands do everything on a fresh machine.
#   make run    create .venv, install the pinned dependencies, build the case-2 map (reach map +
#               10,000 sampled edges) on the CPU
#   make test   the same set-up, then the test suite
PYTHON ?= python3
VENV ?= .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed

.PHONY: run test lint bench clean

$(STAMP): pyproject.toml requirements.lock
	$(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --disable-pip-version-check -r requirements.lock
	$(BIN)/python -m pip install --quiet --disable-pip-version-check --no-deps -e .
	touch $(STAMP)

run: $(STAMP)
	$(BIN)/lmjx build-map --failure case2 --out maps/case2.h5

test: $(STAMP)
	$(BIN)/ruff check lmjx kernels tests benchmarks
	$(BIN)/python -m pytest -q --durations=15 tests

lint: $(STAMP)
	$(BIN)/ruff check lmjx kernels tests benchmarks

bench: $(STAMP)
	$(BIN)/lmjx bench

clean:
	rm -rf $(VENV) .pytest_cache .ruff_cache
