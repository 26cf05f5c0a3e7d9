# Two commands on a fresh machine with python3 (3.11+) and make:
#   make demo   set up .venv and run the whole chain on the built-in simulated campaign
#   make test   set up .venv and headless Chromium, then run the test suite (no test may skip)
# .venv gets the exact versions of constraints.txt; pyproject.toml states the compatible ranges.

# The first Python >= 3.11 among these makes the venv (or: make PYTHON=/path/to/python3.12).
# Not 3.10: gtsam has no stable release for it that works with numpy 2 (bench/results/install.md).
PYTHON_CANDIDATES := python3 python3.13 python3.12 python3.11
ifeq ($(origin PYTHON), undefined)
PYTHON := $(shell for p in $(PYTHON_CANDIDATES); do \
	$$p -c 'import sys; sys.exit(sys.version_info < (3, 11))' >/dev/null 2>&1 && { echo $$p; break; }; done)
endif
VENV   := .venv
BIN    := $(VENV)/bin
STAMP  := $(VENV)/.installed
# The report's screenshot test renders in headless Chromium; `make test` installs Debian's
# package when this path is missing and we are root (or: make test CHROMIUM=/path/to/chromium).
CHROMIUM ?= /usr/bin/chromium
export CHROMIUM

.PHONY: demo test setup browser bench clean

setup: $(STAMP)

$(STAMP): pyproject.toml constraints.txt
	@if [ -z "$(PYTHON)" ] || ! $(PYTHON) -c 'import sys; sys.exit(sys.version_info < (3, 11))' 2>/dev/null; then \
		echo "make: needs Python 3.11 or newer, and $(or $(PYTHON) is not,none of $(PYTHON_CANDIDATES) is); install one, or run make PYTHON=/path/to/python3.11" >&2; \
		exit 1; fi
	@test -x $(BIN)/python || $(PYTHON) -m venv $(VENV) || { \
		echo "make: '$(PYTHON) -m venv' failed; on Debian or Ubuntu install the python3-venv package" >&2; exit 1; }
	$(BIN)/python -m pip install --quiet --upgrade pip
	$(BIN)/python -m pip install --quiet -c constraints.txt -e '.[test,dask]'
	touch $(STAMP)

browser:
	@if [ -x "$(CHROMIUM)" ]; then exit 0; \
	elif [ "$(CHROMIUM)" = /usr/bin/chromium ] && [ "$$(id -u)" = 0 ] && command -v apt-get >/dev/null; then \
		echo "make: installing headless Chromium (Debian package chromium) for the report's screenshot test"; \
		export DEBIAN_FRONTEND=noninteractive; \
		apt-get update -qq >/dev/null && apt-get install -y -qq chromium >/dev/null; \
		test -x "$(CHROMIUM)" || { echo "make: apt-get could not install chromium" >&2; exit 1; }; \
	else \
		echo "make: $(CHROMIUM) is missing; the report's screenshot test needs headless Chromium:" \
			"as root, apt-get install chromium (Debian), or make test CHROMIUM=/path/to/chromium" >&2; \
		exit 1; fi

demo: $(STAMP)
	$(BIN)/sindy-ekf demo

# SINDY_EKF_NO_SKIPS=1: a skipped test fails the run (tests/conftest.py); -n auto: one pytest
# worker per core (pytest-xdist), skips still counted by the controller; --dist loadfile: each test file
# runs on one worker, so its module fixtures (a model, a diagnosis) are made once, not per worker;
# --no-loadscope-reorder: files in the order tests/conftest.py sorts them (the longest first)
test: $(STAMP) browser
	SINDY_EKF_NO_SKIPS=1 $(BIN)/python -m pytest -q -n auto --dist loadfile --no-loadscope-reorder

bench: $(STAMP)
	$(BIN)/python -m bench.run_all

clean:
	rm -rf $(VENV) build *.egg-info
