# Quick start: `make study` then `make test`. Both create .venv on first use.
PYTHON ?= python3
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed
export MUJOCO_GL ?= egl

.PHONY: study test test-slow bench clean

# torch first: torch==2.13.0 is the CPU wheel on disk here; an unpinned torch pulls a CUDA build.
$(STAMP): pyproject.toml
	test -x $(BIN)/python || $(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip
	$(BIN)/python -m pip install --quiet --no-compile torch==2.13.0
	$(BIN)/python -m pip install --quiet --no-compile -e '.[dev]'
	touch $(STAMP)

study: $(STAMP)
	$(BIN)/pmspm study

# Two workers (pytest-xdist; tests/conftest.py keeps a module's shared fixtures in one worker
# and compiles the numba kernels once before the workers start).
test: $(STAMP)
	$(BIN)/ruff check .
	$(BIN)/python -m pytest -n 2

# Every test marked slow (pyproject deselects them from `make test`): the claims that take
# minutes (pruning safety, the search against the seed's design, the image-mode runs).
test-slow: $(STAMP)
	$(BIN)/python -m pytest -m slow

bench: $(STAMP)
	for b in benchmarks/bench_*.py; do $(BIN)/python $$b || exit 1; done

clean:
	rm -rf $(VENV) runs .pytest_cache .ruff_cache
