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
	$(BIN)/pytest -q -n auto

# The tables of docs/results.md (hours on two cores). DATA: made by ../shared/data/unpack all DATA.
bench: $(BIN)/python
	@test -n "$(DATA)" || { echo "usage: make bench DATA=FOLDER"; exit 2; }
	$(BIN)/pip install -q -e '.[cholmod,fast]'
	$(BIN)/python benchmarks/results.py --data-root $(DATA) --doc docs/results.md
	$(BIN)/python benchmarks/world.py --data-root $(DATA) --doc docs/results.md

# The per-mesh, index and partial query figures of docs/performance.md; the indexes go in SCRATCH.
SCRATCH ?= ../cfsig-bench
bench-perf: $(BIN)/python
	@test -n "$(DATA)" || { echo "usage: make bench-perf DATA=FOLDER [SCRATCH=DIR]"; exit 2; }
	$(BIN)/pip install -q -e '.[cholmod,fast]'
	$(BIN)/python benchmarks/per_mesh.py --data $(DATA)/shrec07
	$(BIN)/python benchmarks/index_scale.py --dir $(SCRATCH) --sizes 1000000
	$(BIN)/cfsig index $(DATA)/shrec07 -o $(SCRATCH)/shrec07-cells --partial-cells
	$(BIN)/python benchmarks/partial_speed.py --index-dir $(SCRATCH) --rows 1000000 \
		--real $(SCRATCH)/shrec07-cells

clean:
	rm -rf $(VENV) cfsig-demo .pytest_cache .ruff_cache .mypy_cache .hypothesis
