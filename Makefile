# plantkg: `make test` installs what is missing (scripts/setup.sh) and runs the whole suite.
# Pass pytest options with PYTEST_ARGS, e.g. make test PYTEST_ARGS='-m "not integration"'

SHELL := /bin/bash
VENV := .venv
PYTEST_ARGS ?=

.PHONY: setup test lint

setup:
	bash scripts/setup.sh

test: setup
	$(VENV)/bin/python -m pytest $(PYTEST_ARGS)

lint: setup
	$(VENV)/bin/lint-imports
