# Two entry points do all set-up on a fresh machine (Python 3.11, pip, make, git):
#   make demo   -> create .venv, install trafficgeo, run the demo on a generated scene with known truth
#   make test   -> create .venv, install trafficgeo with test tools, run ruff and the test suite
#   make test-fast -> ruff and the tests not marked slow (under a minute; no browser needed)
PYTHON ?= python3
VENV   ?= .venv
BIN    := $(VENV)/bin

.PHONY: demo test test-fast lint bench clean

$(BIN)/python:
	$(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip

$(VENV)/.installed: pyproject.toml | $(BIN)/python
	$(BIN)/python -m pip install --quiet -e '.[test,cluster]'
	touch $@

demo: $(VENV)/.installed
	$(BIN)/trafficgeo demo --out demo-out

lint: $(VENV)/.installed
	$(BIN)/ruff check src tests benchmarks examples tools

# The browser tests drive Debian's Chromium through Playwright (no browser download).
CHROMIUM ?= /usr/bin/chromium
SUDO := $(shell [ "$$(id -u)" = 0 ] || echo sudo)

$(CHROMIUM):
	$(SUDO) apt-get install -y --no-install-recommends chromium || \
	  ($(SUDO) apt-get update && $(SUDO) apt-get install -y --no-install-recommends chromium)

test: $(VENV)/.installed lint $(CHROMIUM)
	TRAFFICGEO_CHROMIUM=$(CHROMIUM) $(BIN)/python -m pytest -q

test-fast: $(VENV)/.installed lint
	$(BIN)/python -m pytest -q -m "not slow"

bench: $(VENV)/.installed
	$(BIN)/python benchmarks/bench_calibration.py
	$(BIN)/python benchmarks/bench_geo.py
	$(BIN)/python benchmarks/bench_traffic.py

clean:
	rm -rf $(VENV) demo-out .pytest_cache .ruff_cache
