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

.PHONY: all venv demo test bench diagnosis-reports clean test-slow

all: venv

venv: $(STAMP)

$(STAMP): requirements.txt setup.py
	test -x $(PY) || $(PYTHON) -m venv $(VENV)
	$(PY) -m pip install --disable-pip-version-check -q -r requirements.txt
	$(PY) -m pip install --disable-pip-version-check -q --no-deps --no-build-isolation -e .
	touch $(STAMP)

demo: $(STAMP)
	$(PY) -m quad_modelling.demo

# Two pytest-xdist workers (the 2 cores of the target machine; TEST_WORKERS=0: one process): a test file per
# worker at a time, the ROS tests one after another on one worker, the longest files first (test/parallel.py).
TEST_WORKERS ?= 2

test: $(STAMP)
	$(PY) -m pytest -q -n $(TEST_WORKERS) -m "not slow" test

# The slow scenario tests, which CI runs after `make test`: marked `slow`, every test that took over about 6 s of a
# `make test` on a slow 2-core machine (the diagnosis scenarios, run-bag's live graphs, the Dask failure cases, the
# --validate runs, the README tour, the two-host DDS test; see test/conftest.py).
test-slow: $(STAMP)
	$(PY) -m pytest -q -n $(TEST_WORKERS) -m slow test

bench: $(STAMP)
	$(PY) bench/run_all.py

# The NanoBench diagnosis reports under docs/ (needs ../shared/data/nanobench). Each OUTDIR is replaced
# whole by --force (no stale figures), so the two reports live in sibling directories.
NANOBENCH ?= ../shared/data/nanobench
NB = $(addprefix $(NANOBENCH)/,$(addsuffix .csv.gz,$(1)))
SPEED_TRAIN := B2_circle_slow_rep2 B2_circle_medium_rep2 B3_figure8_slow_rep2 B3_figure8_medium_rep2 B5_helix_slow_rep1 \
	B5_helix_medium_rep1 B7_oval_slow_rep2 B7_oval_medium_rep2 B9_trefoil_slow_rep1 B9_trefoil_medium_rep1
SPEED_TEST := B2_circle_fast_rep2 B3_figure8_fast_rep2 B5_helix_fast_rep1 B7_oval_fast_rep2 B9_trefoil_fast_rep1 B9_trefoil_fast_rep2
SHAPE_TRAIN := B2_circle_fast_rep2 B2_circle_medium_rep2 B2_circle_slow_rep2 B3_figure8_fast_rep2 B3_figure8_medium_rep2 \
	B3_figure8_slow_rep2 B6_linear_ramp_rep1 B6_linear_ramp_rep2 B7_oval_fast_rep2 B7_oval_medium_rep2 B7_oval_slow_rep2
SHAPE_TEST := B5_helix_fast_rep1 B5_helix_medium_rep1 B5_helix_slow_rep1 B9_trefoil_fast_rep1 B9_trefoil_medium_rep1 \
	B9_trefoil_slow_rep1 B9_trefoil_fast_rep2

diagnosis-reports: $(STAMP)
	$(VENV)/bin/quad-modelling diagnose --train $(call NB,$(SPEED_TRAIN)) --test $(call NB,$(SPEED_TEST)) \
		--skip-bad --force -o docs/diagnosis_nanobench
	$(VENV)/bin/quad-modelling diagnose --train $(call NB,$(SHAPE_TRAIN)) --test $(call NB,$(SHAPE_TEST)) \
		--skip-bad --force -o docs/diagnosis_nanobench_by_shape

clean:
	rm -rf build install log .pytest_cache
