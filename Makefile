# thermocomp: `make run` serves the daemon on the simulated bench; `make test` checks everything.
PYTHON ?= python3
VENV ?= .venv
BIN := $(VENV)/bin
CONFIG ?= config/sim.toml
SOURCES := daemon drivers api config

.PHONY: run test test-fast lint docs bench soak clean lock

# The exact, hashed dependency set (pip-compile --generate-hashes): every install uses it,
# so a fresh clone, the Docker image and CI test and run the same versions. `make lock`
# refreshes it from pyproject.toml's ranges.
LOCK := requirements.lock
DEV_LOCK := requirements-dev.lock

$(BIN)/python:
	$(PYTHON) -m venv $(VENV)

# Stamps: reinstall only when the lock or the packaging changes.
$(VENV)/.installed: pyproject.toml $(LOCK) | $(BIN)/python
	$(BIN)/python -m pip install --quiet --require-hashes -r $(LOCK)
	$(BIN)/python -m pip install --quiet --no-deps --no-build-isolation -e .
	touch $@

$(VENV)/.installed-dev: pyproject.toml $(DEV_LOCK) | $(BIN)/python
	$(BIN)/python -m pip install --quiet --require-hashes -r $(DEV_LOCK)
	$(BIN)/python -m pip install --quiet --no-deps --no-build-isolation -e .
	touch $(VENV)/.installed $@

# Re-resolve every dependency to the newest versions pyproject.toml allows, with hashes.
PIP_COMPILE := $(BIN)/pip-compile --quiet --generate-hashes --allow-unsafe --all-build-deps --strip-extras \
	--no-emit-index-url --no-emit-find-links
lock: $(VENV)/.installed-dev
	$(PIP_COMPILE) --upgrade --extra dev --extra parquet -o $(DEV_LOCK) pyproject.toml
	$(PIP_COMPILE) -c $(DEV_LOCK) -o $(LOCK) pyproject.toml

run: $(VENV)/.installed
	$(BIN)/thermocomp serve --config $(CONFIG)

lint: $(VENV)/.installed-dev
	$(BIN)/ruff check .
	$(BIN)/ruff format --check $(SOURCES) tests benchmarks
	$(BIN)/mypy

# The documentation site (mkdocs.yml): built with warnings as errors, offline; the reference
# pages are generated from the code at build time (docs/_hooks/reference.py). Output: build/site.
docs: $(VENV)/.installed-dev
	NO_MKDOCS_2_WARNING=1 $(BIN)/mkdocs build --strict --quiet

# The suite on every core (pytest-xdist): one worker a core (TEST_WORKERS=0: one process);
# each test module runs whole on one worker (--dist loadfile), as it would alone: its module
# fixtures are built once and its tests never run beside each other. Not loadgroup: with
# pytest 9.2, xdist 3.8's groups are silently ignored (it renames items through a field
# pytest no longer reads). Each worker has its own tmp_path tree, free ports and fixtures;
# tests/conftest.py's tree guard and timeouts work per worker.
TEST_WORKERS ?= auto
PYTEST_XDIST := -n $(TEST_WORKERS) --dist loadfile

test: lint docs
	@command -v chromium >/dev/null || { echo "make test: the dashboard test drives Debian's" \
		"chromium: sudo apt-get install chromium (.ci/run installs it)"; exit 1; }
	$(BIN)/python -m pytest $(PYTEST_XDIST)

# The tests not marked slow (each under ~5 s on a loaded 2-core machine), no lint, no docs:
# the loop while editing. `make test` runs everything, as CI does.
test-fast: $(VENV)/.installed-dev
	$(BIN)/python -m pytest $(PYTEST_XDIST) -m "not slow"

bench: $(VENV)/.installed-dev
	@set -e; for script in benchmarks/bench_*.py; do \
		echo "== $$script"; $(BIN)/python $$script; done

# Long run at a 20 ms step with WebSocket clients and polling (issue 10); not part of `test`.
SOAK_S ?= 3600
soak: $(VENV)/.installed-dev
	SOAK_S=$(SOAK_S) $(BIN)/python benchmarks/soak.py

clean:
	rm -rf $(VENV) .mypy_cache .ruff_cache .pytest_cache
