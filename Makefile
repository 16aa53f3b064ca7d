# cfsig: `make demo` installs and runs the built-in demo; `make test` installs and runs the tests.
PYTHON ?= python3
VENV ?= .venv
BIN := $(VENV)/bin

.PHONY: demo test lint bench bench-perf clean

$(BIN)/python:
	$(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install -q --upgrade pip

demo: $(BIN)/python
	$(BIN)/pip install -q -e '.[cholmod,fast,plots]'
	$(BIN)/cfsig demo --out cfsig-demo

test: $(BIN)/python
	$(BIN)/pip install -q -e '.[test]'
	$(BIN)/ruff check cfsig tests benchmarks
	$(BIN)/ruff format --check cfsig tests benchmarks
	$(BIN)/mypy
	$(BIN)/pytest -q

bench: $(BIN)/python
	$(BIN)/pip install -q -e '.[test,bench]'
	$(BIN)/python benchmarks/retrieval.py

# The per-mesh and indexing figures of docs/performance.md (about 35 minutes on two cores).
bench-perf: $(BIN)/python
	$(BIN)/pip install -q -e '.[bench,cholmod,dask]'
	$(BIN)/python benchmarks/per_mesh.py
	$(BIN)/python benchmarks/parsers.py
	$(BIN)/python benchmarks/solvers.py
	$(BIN)/python benchmarks/shapedna.py
	$(BIN)/python benchmarks/index_jobs.py

clean:
	rm -rf $(VENV) cfsig-demo .pytest_cache .ruff_cache .mypy_cache .hypothesis
