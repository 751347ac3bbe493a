# Two entry points do all set-up on a fresh machine (Python 3.11, pip, make, git):
#   make demo   -> create .venv, install trafficgeo, run the demo on a generated scene with known truth
#   make test   -> create .venv, install trafficgeo with test tools, run ruff and the test suite
#   make test-fast -> ruff and the tests not marked slow (under a minute; no browser needed)
#   make test-other-simd -> the reference tests again under another SIMD dispatch (part of make test)
#   make docs   -> build the docs site offline into build/site with --strict (part of make test)
PYTHON ?= python3
VENV   ?= .venv
BIN    := $(VENV)/bin

.PHONY: demo test test-fast test-other-simd lint docs bench clean

$(BIN)/python:
	$(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip

$(VENV)/.installed: pyproject.toml | $(BIN)/python
	$(BIN)/python -m pip install --quiet -e '.[test,cluster,docs]'
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

# The reference tests (marked `reference`: they compare with outputs stored in tests/data) run a second time under
# another SIMD dispatch: numpy without its AVX2/AVX-512 paths, OpenCV without AVX/AVX2/AVX-512, OpenBLAS's Nehalem
# (SSE4.2) kernels. A comparison that holds only on the CPU it was written on fails here too (tests/reference_values.py).
ifeq ($(shell uname -m),x86_64)
OTHER_SIMD ?= NPY_DISABLE_CPU_FEATURES="X86_V3 X86_V4 AVX512_ICL AVX512_SPR" \
	OPENCV_CPU_DISABLE="AVX512-SKX,AVX2,FMA3,FP16,AVX" OPENBLAS_CORETYPE=Nehalem
endif

test: $(VENV)/.installed lint $(CHROMIUM)
	TRAFFICGEO_CHROMIUM=$(CHROMIUM) $(BIN)/python -m pytest -q
	$(MAKE) --no-print-directory test-other-simd
	$(MAKE) --no-print-directory docs

# The docs site: mkdocs-material, the API reference from the docstrings (mkdocstrings), the CLI reference from the
# commands (mkdocs-click); offline (no web fonts; Material's offline plugin) and --strict (a broken link fails).
docs: $(VENV)/.installed
	NO_MKDOCS_2_WARNING=1 $(BIN)/mkdocs build --strict --quiet

test-other-simd: $(VENV)/.installed
	@echo 'reference tests under another SIMD dispatch: $(or $(OTHER_SIMD),none on this CPU)'
	$(OTHER_SIMD) $(BIN)/python -m pytest -q -m reference

test-fast: $(VENV)/.installed lint
	$(BIN)/python -m pytest -q -m "not slow"

bench: $(VENV)/.installed
	$(BIN)/python benchmarks/bench_calibration.py
	$(BIN)/python benchmarks/bench_geo.py
	$(BIN)/python benchmarks/bench_traffic.py

clean:
	rm -rf $(VENV) demo-out build .pytest_cache .ruff_cache
