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
	$(BIN)/python -m pip install --quiet -e '.[dev,dask]'
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

# The socketcan lane (tests/hil/test_socketcan_lane.py) boots a one-CPU user-mode Linux guest
# for about 3-4 minutes.  It runs beside the lock-step tests (unit, integration), which do not
# mind sharing the machine; the real-time, fuzz and safety tests (hil, safety) run after it,
# alone.  `make test` fails if any part fails.  LANE=0 runs everything in one pytest.
LANE ?= 1
LANE_TEST := tests/hil/test_socketcan_lane.py
LANE_LOG := $(OUT)/socketcan-lane.log

test: lint
ifeq ($(LANE),1)
	@mkdir -p $(OUT)
	@echo "socketcan lane: $(LANE_TEST) beside tests/unit and tests/integration, output in $(LANE_LOG)"
	@$(BIN)/python -m pytest -q -p no:cacheprovider --basetemp=$(OUT)/socketcan-lane-tmp \
		$(LANE_TEST) > $(LANE_LOG) 2>&1 & lane=$$!; \
	$(BIN)/python -m pytest -q tests/unit tests/integration; quiet=$$?; \
	wait $$lane; lane_rc=$$?; \
	echo "--- socketcan lane ($(LANE_TEST)), exit $$lane_rc:"; cat $(LANE_LOG); \
	$(BIN)/python -m pytest -q tests/hil tests/safety --deselect $(LANE_TEST); alone=$$?; \
	test $$quiet -eq 0 && test $$lane_rc -eq 0 && test $$alone -eq 0
else
	$(BIN)/python -m pytest -q
endif

clean:
	rm -rf $(VENV) $(OUT) .pytest_cache .mypy_cache .ruff_cache
