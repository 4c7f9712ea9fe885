# vigil: `make run` runs the main job, `make test` runs the tests.
# Both set everything up first (Debian packages, .venv, Python dependencies).
VENV ?= .venv
PY := $(VENV)/bin/python
export MUJOCO_GL ?= egl
export PYOPENGL_PLATFORM ?= egl
export ROS_AUTOMATIC_DISCOVERY_RANGE ?= LOCALHOST

.PHONY: setup run replay test lint bench
setup:
	@bash scripts/setup.sh

run: setup
	$(VENV)/bin/vigil run scenarios/5.2.2.yaml --out runs/main

replay: setup
	$(VENV)/bin/vigil replay-report --out runs/replay

test: setup
	$(PY) -m pytest -q $(PYTEST_ARGS)

lint: setup
	$(VENV)/bin/ruff check . && $(VENV)/bin/ruff format --check . && $(VENV)/bin/mypy

bench: setup
	$(PY) bench/run_all.py
