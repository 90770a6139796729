# Two entry points for a fresh machine: `make run` (default scene and its report) and `make test`.
PYTHON ?= python3
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed

.PHONY: run test test-all bench validate stability clean

$(STAMP): pyproject.toml
	test -x $(BIN)/python || $(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip
	$(BIN)/python -m pip install --quiet -e ".[test,report]"
	touch $(STAMP)

run: $(STAMP)
	$(BIN)/lieseries run default --out reports/default

# Bytecode is written for the tests even where PYTHONDONTWRITEBYTECODE is set: the suite starts ~60 Python
# processes (workers, CLI runs, fresh-interpreter checks), and each would otherwise compile the package (~1 s).
test: $(STAMP)
	PYTHONDONTWRITEBYTECODE= $(BIN)/python -m pytest -q -n 2

test-all: $(STAMP)
	PYTHONDONTWRITEBYTECODE= $(BIN)/python -m pytest -q -n 2 -m ""

bench: $(STAMP)
	$(BIN)/python benchmarks/run_all.py

validate: $(STAMP)
	$(BIN)/python validation/run_all.py

stability: $(STAMP)
	$(BIN)/python validation/stability.py

clean:
	rm -rf $(VENV) reports .pytest_cache
