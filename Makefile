# One command each: `make demo` (set up, then the demo on simulated hardware) and `make test`.
# Setup creates .venv at the repository root and installs the project with its test tools.
PYTHON ?= python3
VENV := .venv
STAMP := $(VENV)/.installed-stamp

.PHONY: setup compile demo test test-all test-vcan lint docs bench clean

$(STAMP): pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(VENV)/bin/pip install --quiet --upgrade pip
	$(VENV)/bin/pip install --quiet -e '.[dev]'
	touch $(STAMP)

# The cycle's modules compiled by mypyc (controller/compiled_law.py), again whenever a source in
# their folders changed: a compilation older than its source is not used (the law then runs from
# its sources, and a run says so), so make keeps the two together. make compile: unconditionally.
LAW := controller/compiled_law.json
# Without a C compiler the set-up goes on and the law runs from its sources (slower; runs say so).
$(LAW): $(STAMP) $(wildcard controller/compiled_law.py controller/core/*.py controller/tasks/*.py controller/robots/*.py controller/robots/cheope/*.py drivers/*.py sim_backend/*.py)
	$(VENV)/bin/python -m controller.tools.compile_law || \
		echo "make: the cycle's modules were not compiled (above: why); they run from their sources"

setup: $(STAMP) $(LAW)

compile: $(STAMP)
	$(VENV)/bin/python -m controller.tools.compile_law

demo: setup
	$(VENV)/bin/cheope demo

# make test: the static checks and the fast layers (tests/unit, tests/protocol without the slow
# tier): 178 and 237 s on the 2-core development VM once set up (2026-12-03). make test-all: the
# static checks and every layer but vcan (what CI runs).
# The in-process tests in two worker processes (pytest-xdist), one per core of the 2-core machines;
# the tests that run controller processes over a bus (marker bus_processes, tests/conftest.py) after
# them, one at a time, as they were made to run: beside a second worker they failed.
PYTEST_WORKERS ?= 2
test: lint
	$(VENV)/bin/pytest -q -n $(PYTEST_WORKERS) tests/unit tests/protocol -m "not slow and not vcan and not bench and not bus_processes"
	$(VENV)/bin/pytest -q tests/unit tests/protocol -m "not slow and not vcan and not bench and bus_processes"

test-all: lint
	$(VENV)/bin/pytest -q -n $(PYTEST_WORKERS) -m "not vcan and not bench and not bus_processes"
	$(VENV)/bin/pytest -q -m "bus_processes and not vcan and not bench"

test-vcan: setup
	tests/vcan/run

# Static checks: ruff's rule set and its formatter on the whole tree ([tool.ruff] in pyproject.toml),
# mypy with the profile there ([tool.mypy]).
lint: setup
	$(VENV)/bin/ruff check .
	$(VENV)/bin/ruff format --check .
	$(VENV)/bin/mypy

# The documentation site into site/; --strict turns every broken link or missing page into an error.
# It needs the docs extra only: the dev venv where make setup made one, else a venv of its own with
# the project and the docs extra (no ROS 2 wheels, no test tools).
DOCS_VENV := .venv-docs
$(DOCS_VENV)/.installed-stamp: pyproject.toml
	$(PYTHON) -m venv $(DOCS_VENV)
	$(DOCS_VENV)/bin/pip install --quiet --upgrade pip
	$(DOCS_VENV)/bin/pip install --quiet -e '.[docs]'
	touch $@

docs:
	@if [ -f $(STAMP) ]; then mkdocs=$(VENV)/bin/mkdocs; \
	else $(MAKE) --no-print-directory $(DOCS_VENV)/.installed-stamp && mkdocs=$(DOCS_VENV)/bin/mkdocs; fi; \
	NO_MKDOCS_2_WARNING=1 $$mkdocs build --strict --quiet

# The bench runs cyclictest (Debian rt-tests) beside each case for the machine's floor: installed
# here when missing and this is root, as tests/vcan/run installs its tools; else the bench says so.
bench: setup
	@command -v cyclictest >/dev/null || { [ "$$(id -u)" = 0 ] && command -v apt-get >/dev/null && \
		{ apt-get update -qq && apt-get install -y -qq --no-install-recommends rt-tests; } >/dev/null 2>&1; } || true
	$(VENV)/bin/cheope bench $(BENCH_ARGS)

clean:
	-[ -x $(VENV)/bin/python ] && $(VENV)/bin/python -m controller.tools.compile_law --clean
	rm -rf $(VENV) $(DOCS_VENV) *.egg-info .pytest_cache .hypothesis site
