# Set-up and the README's two quick-start commands.
# torch==2.13.0 (the CPU build) is installed before the package so that the package's
# torch range is already satisfied and pip never pulls the multi-GB CUDA wheels.
PYTHON ?= python3
VENV   ?= .venv
BIN    := $(VENV)/bin
STAMP  := $(VENV)/.pmsr-installed

.PHONY: setup demo test test-integration test-all bench clean

setup: $(STAMP)

$(STAMP): pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(BIN)/pip install --quiet torch==2.13.0
	$(BIN)/pip install --quiet -e ".[dev]"
	touch $(STAMP)

demo: setup
	$(BIN)/pmsr demo

# Two pytest-xdist workers, one thread each: the 2 cores of the development machine, no oversubscription.
test: setup
	OMP_NUM_THREADS=1 $(BIN)/python -m pytest -q -n 2 --dist worksteal

# End-to-end runs and the longer checks (each 4 s or more): CI runs them after `test`.
test-integration: setup
	OMP_NUM_THREADS=1 $(BIN)/python -m pytest -q -n 2 --dist worksteal -m "integration and not slow"

test-all: setup
	OMP_NUM_THREADS=1 $(BIN)/python -m pytest -q -n 2 --dist worksteal -m ""

bench: setup
	$(BIN)/python benchmarks/simulate_throughput.py

clean:
	rm -rf $(VENV) runs .pytest_cache
