# Two commands on a fresh machine:  `make demo`  and  `make test`.
VENV ?= .venv
PYTEST_ARGS ?=

.PHONY: setup demo test bench docs clean

setup:
	@bash scripts/bootstrap.sh

demo: setup
	$(VENV)/bin/sionna-mmir demo

# one test process per core, a test file per process at a time (module fixtures built once)
test: setup
	$(VENV)/bin/python -m pytest -q -n auto --dist loadfile $(PYTEST_ARGS)

# benchmarks may run long: no per-test time limit
bench: setup
	$(VENV)/bin/python -m pytest -q -m benchmark -s --timeout 0 benchmarks $(PYTEST_ARGS)

docs: setup
	$(VENV)/bin/python -m sphinx -W --keep-going -b html docs docs/_build/html

clean:
	rm -rf $(VENV) build *.egg-info .pytest_cache docs/_build
