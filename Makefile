# eha_health developer entry points.  Needs only python3 (>= 3.10) on PATH.
#   make demo   - set up .venv (with the ros and test extras) and run the demo
#   make test   - set up .venv and run the test suite
#   make test-fast  - the suite without the slow node-graph tests (pytest -m "not graph")
#   make test-graph - only the node-graph tests (pytest -m graph)
#   make bench  - set up .venv and run the speed and graph benchmarks
#   make bags   - regenerate the committed recordings in bags/
#   make golden-check - re-run the golden outputs (tests/golden/) and compare (tools/golden.py)
#   make venv   - (alias: setup) only set up .venv
#   make clean  - remove .venv and build/test leftovers

PYTHON ?= python3
VENV := .venv
STAMP := $(VENV)/.eha-health-installed
PYTEST_ARGS ?=

# Keep rcl's logs inside the work tree (not ~/.ros) and DDS discovery local.
export ROS_LOG_DIR ?= $(CURDIR)/.ros/log
export ROS_AUTOMATIC_DISCOVERY_RANGE ?= LOCALHOST

.PHONY: demo test test-fast test-graph bench bags golden-check venv setup clean

demo: $(STAMP)
	$(VENV)/bin/eha-health demo

test: $(STAMP)
	$(VENV)/bin/python -m pytest -q tests $(PYTEST_ARGS)

test-fast: $(STAMP)
	$(VENV)/bin/python -m pytest -q tests -m "not graph" $(PYTEST_ARGS)

test-graph: $(STAMP)
	$(VENV)/bin/python -m pytest -q tests -m graph $(PYTEST_ARGS)

bench: $(STAMP)
	$(VENV)/bin/eha-health bench speed
	$(VENV)/bin/eha-health bench graph

bags: $(STAMP)
	EHA=$(VENV)/bin/eha-health bash bags/make_bags.sh

golden-check: $(STAMP)
	$(VENV)/bin/python tools/golden.py check

venv setup: $(STAMP)

# The install is redone only when the packaging metadata changes.
$(STAMP): setup.py setup.cfg
	test -x $(VENV)/bin/python || $(PYTHON) -m venv $(VENV)
	$(VENV)/bin/pip install --quiet --upgrade pip
	$(VENV)/bin/pip install -e ".[ros,test]"
	touch $@

clean:
	rm -rf $(VENV) build install log .ros .pytest_cache *.egg-info src/*.egg-info
	find . -path ./.git -prune -o -type d -name __pycache__ -prune -exec rm -rf {} +
