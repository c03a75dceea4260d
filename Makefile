# missing-link: `make demo` and `make test` work on a fresh clone (Python >= 3.11, make, git).
# Everything Python goes into .venv; the MicroPython test runtime comes from npm into node_modules.
PYTHON ?= python3
VENV   ?= .venv
PY     := $(VENV)/bin/python
STAMP  := $(VENV)/.installed-stamp
NODE_STAMP := node_modules/.installed-stamp
DURATION ?= 20

.PHONY: demo test lint typecheck unit bench venv node clean system-deps

venv: $(STAMP)

$(STAMP): pyproject.toml
	@test -x $(PY) || $(PYTHON) -m venv $(VENV)
	$(PY) -m pip install --quiet --upgrade pip
	$(PY) -m pip install --quiet -e '.[dev]'
	@touch $@

# Node.js + npm come from Debian if missing (scripts/system-deps.sh is idempotent).
node: $(NODE_STAMP)

$(NODE_STAMP): package.json
	@command -v node >/dev/null 2>&1 && command -v npm >/dev/null 2>&1 || bash scripts/system-deps.sh
	npm install --no-audit --no-fund --loglevel=error
	@touch $@

system-deps:
	bash scripts/system-deps.sh

demo: venv
	$(VENV)/bin/missing-link demo --duration $(DURATION)

lint: venv
	$(VENV)/bin/ruff check src tests bench
	$(VENV)/bin/ruff format --check src tests bench

typecheck: venv
	$(VENV)/bin/mypy

unit: venv node
	$(VENV)/bin/pytest -q

test: lint typecheck unit

bench: venv
	$(PY) bench/bench_codec.py
	$(PY) bench/bench_rpc.py
	$(PY) bench/bench_daemon.py
	$(PY) bench/bench_timesync.py
	$(PY) bench/bench_zenoh.py

clean:
	rm -rf $(VENV) node_modules .mypy_cache .ruff_cache .pytest_cache .hypothesis
