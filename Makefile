# missing-link: `make demo` and `make test` work on a fresh clone (Python >= 3.11, make, git);
# `make check` is the quick inner loop (lint, types, the tests not marked slow).
# Everything Python goes into .venv; the MicroPython test runtime comes from npm into node_modules.
PYTHON ?= python3
VENV   ?= .venv
PY     := $(VENV)/bin/python
STAMP  := $(VENV)/.installed-stamp
NODE_STAMP := node_modules/.installed-stamp
# Real ROS 2 (Kilted) from PyPI wheels, in a venv of its own (their .pth re-execs Python with the
# library path set, which the project venv should not pay for); missing-link is installed into it
# too, as a ROS 2 user would, with the zenoh extra (both ROS 2 faces there: run --help names them,
# bench_zenoh uses it).  `make test` builds it once; the wheels come from pip's cache after.
ROS2_VENV  ?= .venv-ros2
ROS2_STAMP := $(ROS2_VENV)/.installed-stamp
ROS2_WHEELS := ros-kilted-rclpy ros-kilted-std-msgs ros-kilted-sensor-msgs \
	ros-kilted-diagnostic-msgs ros-kilted-rmw-fastrtps-cpp \
	ros-kilted-rosidl-default-generators ros-kilted-rosidl-core-generators \
	ros-kilted-ament-cmake ros-kilted-ament-package ros-kilted-ament-cmake-include-directories \
	ros-kilted-ament-cmake-ros-core catkin-pkg cmake
DURATION ?= 20

.PHONY: demo test check lint typecheck unit bench venv node ros2 clean system-deps

venv: $(STAMP)

$(STAMP): pyproject.toml
	@test -x $(PY) || $(PYTHON) -m venv $(VENV)
	$(PY) -m pip install --quiet --upgrade pip
	$(PY) -m pip install --quiet -e '.[dev]'
	@touch $@

ros2: $(ROS2_STAMP)

$(ROS2_STAMP): pyproject.toml Makefile
	@test -x $(ROS2_VENV)/bin/python || $(PYTHON) -m venv $(ROS2_VENV)
	$(ROS2_VENV)/bin/python -m pip install --quiet --upgrade pip
	$(ROS2_VENV)/bin/python -m pip install --quiet $(ROS2_WHEELS) -e '.[zenoh]'
	@touch $@

# What `make test` uses from the system (Node.js and npm, a C++ compiler, the AVR toolchain,
# simavr) comes from Debian through scripts/system-deps.sh, run on every `make test`: it installs
# whatever is missing and is quiet and quick when nothing is.  `make demo` needs none of it.
system-deps:
	@bash scripts/system-deps.sh

node: $(NODE_STAMP)

$(NODE_STAMP): package.json | system-deps
	npm install --no-audit --no-fund --loglevel=error
	@touch $@

demo: venv
	$(VENV)/bin/missing-link demo --duration $(DURATION)

lint: venv
	$(VENV)/bin/ruff check src tests bench
	$(VENV)/bin/ruff format --check src tests bench

typecheck: venv
	$(VENV)/bin/mypy

# PYTHONDONTWRITEBYTECODE emptied: the tests start hundreds of Python processes (the CLI, board
# processes), each of which would compile the package again (0.66 s against 0.22 s for the daemon's
# imports here).  On every core (pytest-xdist), the tests that must not run side by side in
# groups (tests/conftest.py: SERIAL, and a module's shared fixtures); PYTEST_WORKERS=0: in one
# process.
PYTEST_WORKERS ?= auto
unit: venv system-deps node ros2
	PYTHONDONTWRITEBYTECODE= ML_ROS2_PYTHON=$(abspath $(ROS2_VENV))/bin/python $(VENV)/bin/pytest -q \
		-n $(PYTEST_WORKERS) --dist loadgroup

test: lint typecheck unit

# The inner loop: lint, types and the tests not marked slow (no board processes, MicroPython,
# simavr, ROS or browsers: tests/*.py mark those), under a minute here; on every core as make unit
# (most of these tests wait on sockets and threads: one process used half a core).  `make test`
# runs all.
check: lint typecheck node
	$(VENV)/bin/pytest -q -m "not slow" -n $(PYTEST_WORKERS) --dist loadgroup

bench: venv ros2
	$(PY) bench/bench_codec.py
	$(PY) bench/bench_rpc.py
	$(PY) bench/bench_daemon.py
	$(PY) bench/bench_timesync.py
	ML_ROS2_PYTHON=$(abspath $(ROS2_VENV))/bin/python $(PY) bench/bench_zenoh.py
	$(PY) bench/bench_idle.py
	$(PY) bench/bench_world.py
	$(PY) bench/bench_world_timing.py
	# the soak (minutes, not in make test): $(PY) bench/soak.py --boards 4 --minutes 3

clean:
	rm -rf $(VENV) $(ROS2_VENV) node_modules .mypy_cache .ruff_cache .pytest_cache .hypothesis
