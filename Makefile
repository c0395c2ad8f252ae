# thermocomp: `make run` serves the daemon on the simulated bench; `make test` checks everything.
PYTHON ?= python3
VENV ?= .venv
BIN := $(VENV)/bin
CONFIG ?= config/sim.toml
SOURCES := daemon drivers api config

.PHONY: run test lint bench soak clean

$(BIN)/python:
	$(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip

# Stamps: reinstall only when the packaging changes.
$(VENV)/.installed: pyproject.toml | $(BIN)/python
	$(BIN)/python -m pip install --quiet -e .
	touch $@

$(VENV)/.installed-dev: pyproject.toml | $(BIN)/python
	$(BIN)/python -m pip install --quiet -e ".[dev]"
	touch $(VENV)/.installed $@

run: $(VENV)/.installed
	$(BIN)/thermocomp serve --config $(CONFIG)

lint: $(VENV)/.installed-dev
	$(BIN)/ruff check .
	$(BIN)/ruff format --check $(SOURCES) tests benchmarks
	$(BIN)/mypy

test: lint
	@command -v chromium >/dev/null || { echo "make test: the dashboard test drives Debian's" \
		"chromium: sudo apt-get install chromium (.ci/run installs it)"; exit 1; }
	$(BIN)/python -m pytest

bench: $(VENV)/.installed-dev
	@set -e; for script in benchmarks/bench_*.py; do \
		echo "== $$script"; $(BIN)/python $$script; done

# Long run at a 20 ms step with WebSocket clients and polling (issue 10); not part of `test`.
SOAK_S ?= 3600
soak: $(VENV)/.installed-dev
	SOAK_S=$(SOAK_S) $(BIN)/python benchmarks/soak.py

clean:
	rm -rf $(VENV) .mypy_cache .ruff_cache .pytest_cache
