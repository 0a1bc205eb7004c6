# The two commands of the README:
#   make demo   - set up everything, then run the offline demo
#   make test   - set up everything, then run the test suite
VENV ?= .venv

.PHONY: setup demo test lint bench

setup:
	@bash scripts/setup.sh

demo: setup
	$(VENV)/bin/quash demo

test: setup
	$(VENV)/bin/python -m pytest

lint: setup
	$(VENV)/bin/ruff check .
	$(VENV)/bin/ruff format --check .

bench: setup
	$(VENV)/bin/python benchmarks/bench_inference.py
	$(VENV)/bin/python benchmarks/bench_quality.py
	$(VENV)/bin/python benchmarks/bench_dask.py
