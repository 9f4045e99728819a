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

.PHONY: run verdicts test lint install clean

$(STAMP): pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --no-compile -e '.[bench,eval,live,dev,dask]'
	@# byte-compiled once, on both cores: where PYTHONDONTWRITEBYTECODE is set (as on these
	@# CI machines) no import writes it, and every process would compile numpy, scipy and
	@# the rest from source again ('import controller.node, tools.run.commands' 2.0-2.7 s
	@# against 1.45-1.6 s compiled; compiling takes 26 s)
	$(BIN)/python -m compileall -q -j 0 $(VENV)/lib > /dev/null
	touch $(STAMP)

install: $(STAMP)

run: $(STAMP)
	$(BIN)/wheelchair-hil evaluate --out $(OUT)/eval --seeds $(SEEDS)

# The rank verdicts with noise (docs/evaluation.md "Cost"): setting (a) alone, 5 Monte-Carlo
# replicates of every cell and of the cascaded run besides the nominal one.
verdicts: $(STAMP)
	$(BIN)/wheelchair-hil evaluate --out $(OUT)/verdicts --settings paper --seeds 5

lint: $(STAMP)
	$(BIN)/ruff check .
	$(BIN)/ruff format --check .
	$(BIN)/mypy

# make test: lint, then the lock-step tests on two workers beside the socketcan lane (a
# one-CPU user-mode Linux guest, tests/hil/test_socketcan_lane.py), then the tests that need
# the machine to themselves (marked `alone`: real time); tests/lanes.sh says how, and writes
# each part's wall time to $(OUT)/test-times.txt.  LANE=0 runs everything in one pytest.
LANE ?= 1

test: $(STAMP)
ifeq ($(LANE),1)
	@bash tests/lanes.sh $(BIN) $(OUT)
else
	$(MAKE) lint
	$(BIN)/python -m pytest -q
endif

clean:
	rm -rf $(VENV) $(OUT) .pytest_cache .mypy_cache .ruff_cache
