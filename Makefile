# voxlidar: `make demo` and `make test` each do their own set-up first.
PY := .venv/bin/python
OUT ?= out

.PHONY: setup demo test test-gpu test-slow test-all bench clean

setup:
	@bash scripts/setup.sh

demo: setup
	$(PY) examples/demo.py --out $(OUT)

test: setup
	$(PY) -m pytest -m "not slow and not gpu"

test-gpu: setup
	$(PY) -m pytest -m "gpu"

test-slow: setup
	$(PY) -m pytest -m "slow"

test-all: setup
	$(PY) -m pytest

bench: setup
	@for b in benchmarks/bench_*.py; do echo "== $$b"; $(PY) $$b || exit 1; done
	$(PY) benchmarks/collect.py

clean:
	rm -rf $(OUT) .pytest_cache
