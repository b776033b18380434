# Every target creates .venv on first use and installs the package into it.
PYTHON ?= python3
VENV   := .venv
BIN    := $(VENV)/bin
STAMP  := $(VENV)/.installed

.PHONY: demo test bench lint clean

$(STAMP): pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(BIN)/pip install --quiet --upgrade pip
	$(BIN)/pip install --quiet -e '.[dev]'
	touch $(STAMP)

demo: $(STAMP)
	$(BIN)/imucal calibrate sessions/qureshi18-seed1.h5 --output /tmp/imucal-demo.cal.json
	$(BIN)/imucal report /tmp/imucal-demo.cal.json

test: $(STAMP)
	$(BIN)/python -m pytest -n 2 -q

bench: $(STAMP)
	$(BIN)/python -m bench

lint: $(STAMP)
	$(BIN)/ruff check imucal_cli tests bench

clean:
	rm -rf $(VENV) build *.egg-info .pytest_cache
