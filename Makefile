# Two entry points for a fresh machine (Python 3.11 with venv, gcc, make, iproute2, util-linux):
#   make run    the main job: the paper's experiments through the CAN stack, report and figures
#   make test   lint, type checks and the test suite (unit, integration, multi-process HIL)
PYTHON ?= python3
VENV   := .venv
BIN    := $(VENV)/bin
STAMP  := $(VENV)/.installed
OUT    ?= out
# Monte-Carlo replicates per cell (noise bands, rank verdicts): `make run SEEDS=5`.  The
# default keeps the main job under 10 minutes on 2 cores (docs/evaluation.md "Cost").
SEEDS  ?= 1

.PHONY: run test lint install clean

$(STAMP): pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet -e '.[dev,dask]'
	touch $(STAMP)

install: $(STAMP)

run: $(STAMP)
	$(BIN)/wheelchair-hil evaluate --out $(OUT)/eval --seeds $(SEEDS)

lint: $(STAMP)
	$(BIN)/ruff check .
	$(BIN)/ruff format --check .
	$(BIN)/mypy

test: lint
	$(BIN)/python -m pytest -q

clean:
	rm -rf $(VENV) $(OUT) .pytest_cache .mypy_cache .ruff_cache
