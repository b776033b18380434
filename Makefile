# Every target creates .venv on first use and installs the package into it.
PYTHON ?= python3
VENV   := .venv
BIN    := $(VENV)/bin
STAMP  := $(VENV)/.installed
# Python keeps compiled modules in __pycache__ unless PYTHONDONTWRITEBYTECODE is set, as some CI
# images and containers do; then every `imucal` process compiles the package's 55,000 lines
# again (0.7-0.9 s of CPU each), and the tests start about 150 of them. An empty value is
# Python's default (the cache on), for the commands below and every process they start; the
# tests compile the package once before the workers start (not in every early process at once).
CACHED := PYTHONDONTWRITEBYTECODE=

.PHONY: demo test test-all bench docs lint clean

# Installs with uv (from PyPI into the venv, a wheel only; it resolves and unpacks the ~90
# packages of `.[dev]` in about 12 s where pip takes about 50 s, the same versions), or with pip
# where uv cannot be had or fails (uv reads none of pip's settings: a mirror or proxy only pip
# is told of). uv writes no bytecode: the dependencies (not their own tests) are compiled once,
# on all cores, here rather than by each test worker at once on its first import (a file of a
# dependency that does not compile is that package's, as pip ignores it: `-`).
INSTALL = { [ -x $(BIN)/uv ] && $(BIN)/uv pip install --quiet --python $(BIN)/python $(1); } \
	|| $(BIN)/pip install --quiet $(1)
# $(call) splits its arguments at commas: a list of extras names them through $(COMMA).
COMMA := ,

$(STAMP): pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(BIN)/pip install --quiet --only-binary=:all: uv || echo "uv not available: installing with pip"
	$(call INSTALL,-e '.[dev]')
	-$(CACHED) $(BIN)/python -m compileall -q -j 0 -x '/tests?/' $(VENV)/lib
	touch $(STAMP)

# The demo works on a copy, so the shipped session is never modified.
demo: $(STAMP)
	mkdir -p out
	cp sessions/qureshi18-seed1.h5 out/demo.h5
	rm -f out/demo.cal.json
	$(CACHED) $(BIN)/imucal calibrate out/demo.h5 --output out/demo.cal.json
	$(CACHED) $(BIN)/imucal report out/demo.cal.json

# The suite without its Monte-Carlo and long-session cases (marked `slow`): minutes on 2 cores.
# 8 workers on 2 cores, work stealing: the tests through the virtual device spend most of their
# time waiting for a stream served in real time, and the others run meanwhile; beside two CPU
# burners, 8 workers hold 4/5 of the CPU where 6 held 3/4 and 4 held 2/3 (2,324 tests: 3 min
# 59 s with 6, not 4 min 55 s with 4; 2,489 tests on a day the host ran the same suite 25 %
# slower: 5 min 2 s and 5 min 42 s with 8, 5 min 45 s with 6; the CPU, not the workers, is
# the limit: about 8.5 CPU-minutes, 1 of them the workers' start-up and collection).
test: $(STAMP)
	$(CACHED) $(BIN)/python -m compileall -q imucal_cli tests bench
	$(CACHED) $(BIN)/python -m pytest -n 8 --dist worksteal -q -m "not slow"

# Everything, the slow cases too.
test-all: $(STAMP)
	$(CACHED) $(BIN)/python -m compileall -q imucal_cli tests bench
	$(CACHED) $(BIN)/python -m pytest -n 8 --dist worksteal -q

# The benchmarks also compare with MaD Lab's `imucal` package (the `bench` extra).
$(VENV)/.bench: $(STAMP)
	$(call INSTALL,-e '.[dev$(COMMA)bench]')
	touch $(VENV)/.bench

bench: $(VENV)/.bench
	$(CACHED) $(BIN)/python -m bench

# The user documentation (README.md links into docs/) as a website in site/; --strict fails on a
# broken link or anchor, or a page left out of mkdocs.yml's nav.
$(VENV)/.docs: $(STAMP)
	$(call INSTALL,-e '.[docs]')
	touch $(VENV)/.docs

docs: $(VENV)/.docs
	$(BIN)/mkdocs build --strict --site-dir site

lint: $(STAMP)
	$(BIN)/ruff check imucal_cli tests bench

clean:
	rm -rf $(VENV) build *.egg-info .pytest_cache out site
