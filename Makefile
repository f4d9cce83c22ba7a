# Each target sets up .venv (pinned dependencies) when it is missing or out of date.
PYTHON ?= python3
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed

.PHONY: reproduce test bench clean

$(STAMP): pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(BIN)/pip install --quiet --upgrade pip
	$(BIN)/pip install --quiet -e '.[test]'
	-$(BIN)/rerun analytics disable >/dev/null 2>&1
	touch $(STAMP)

reproduce: $(STAMP)
	$(BIN)/dse reproduce --out out

test: $(STAMP)
	$(BIN)/python -m pytest

bench: $(STAMP)
	$(BIN)/python -m benchmarks.run --out out

clean:
	rm -rf out .dse-cache
