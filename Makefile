# voxlidar: `make demo` and `make test` each do their own set-up first.
PY := .venv/bin/python
OUT ?= out

.PHONY: setup lint docs demo test test-gpu test-slow test-all bench clean

setup:
	@bash scripts/setup.sh

demo: setup
	$(PY) examples/demo.py --out $(OUT)

lint: setup
	.venv/bin/ruff check .
	$(PY) scripts/check_types.py

# the docs site: warnings are errors, then every internal link checked
docs: setup
	rm -rf docs/_build docs/reference/api
	$(PY) -m sphinx -q -W --keep-going -b html docs docs/_build/html
	$(PY) scripts/check_links.py docs/_build/html
	@echo "docs: open docs/_build/html/index.html"

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
	rm -rf $(OUT) .pytest_cache docs/_build docs/reference/api
