# quad_modelling: two commands on a fresh machine.
#   make demo   - the main job on the bundled bag
#   make test   - the test suite
# Both create .venv from requirements.txt when it is missing or older than it.

PYTHON ?= python3
VENV := .venv
PY := $(VENV)/bin/python
STAMP := $(VENV)/.installed
# DDS stays on this machine: loopback discovery only, and a domain of our own.
export ROS_AUTOMATIC_DISCOVERY_RANGE := LOCALHOST
export ROS_DOMAIN_ID ?= 42
export MPLBACKEND := Agg

.PHONY: all venv demo test bench clean

all: venv

venv: $(STAMP)

$(STAMP): requirements.txt setup.py
	test -x $(PY) || $(PYTHON) -m venv $(VENV)
	$(PY) -m pip install --disable-pip-version-check -q -r requirements.txt
	$(PY) -m pip install --disable-pip-version-check -q --no-deps --no-build-isolation -e .
	touch $(STAMP)

demo: $(STAMP)
	$(PY) -m quad_modelling.demo

test: $(STAMP)
	$(PY) -m pytest -q test

bench: $(STAMP)
	$(PY) bench/run_all.py

clean:
	rm -rf build install log .pytest_cache
