# plantkg: `make test` installs what is missing (scripts/setup.sh) and runs the whole suite.
# `make demo` runs the robot cell end to end (DEMO_ARGS, e.g. DEMO_ARGS='--duration 20'), then the AGV
# fleet (FLEET_DEMO_ARGS, e.g. FLEET_DEMO_ARGS='--vehicles 5 --keep 60').
# Pass pytest options with PYTEST_ARGS, e.g. make test PYTEST_ARGS='-m "not integration"'
# PYTEST_WORKERS=N runs the suite on N pytest-xdist workers (a file stays on one worker; every test
# picks free ports and its own tmp dir). Default 4, twice the cores of the 2-core machines it runs
# on: most integration tests wait on brokers and JVMs starting (28-30 min on 2 workers, 19 min on 4
# at 486fd62). PYTEST_WORKERS=0 runs one process. The suite's
# time on a 2-core machine is in the README; the 30 slowest tests are listed at the end of a run.
# `make bench` runs the benchmark studies and rebuilds benchmarks/RESULTS.md (BENCH_ARGS, e.g.
# BENCH_ARGS='load --tiny'; see benchmarks/README.md).

SHELL := /bin/bash
VENV := .venv
PYTEST_ARGS ?=
PYTEST_WORKERS ?= 4
DEMO_ARGS ?=
FLEET_DEMO_ARGS ?=
BENCH_ARGS ?=

.PHONY: setup test lint demo bench

setup:
	bash scripts/setup.sh

test: setup
	$(VENV)/bin/python -m pytest -n $(PYTEST_WORKERS) --dist loadfile --durations=30 $(PYTEST_ARGS)

lint: setup
	$(VENV)/bin/lint-imports

demo: setup
	$(VENV)/bin/plantkg demo $(DEMO_ARGS)
	$(VENV)/bin/plantkg fleet demo $(FLEET_DEMO_ARGS)

bench: setup
	$(VENV)/bin/plantkg-bench $(BENCH_ARGS)
