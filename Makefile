# Two entry points for a fresh machine (Python 3.11 with venv, gcc, make, iproute2, util-linux):
#   make run    the main job: the paper's experiments through the CAN stack, report and figures
#   make test   lint, type checks and the test suite (unit, integration, multi-process HIL)
PYTHON ?= python3
VENV   := .venv
BIN    := $(VENV)/bin
STAMP  := $(VENV)/.installed
OUT    ?= out
# Monte-Carlo replicates per cell (noise bands, paired rank verdicts).  5 keeps the main job
# under 10 minutes on 2 cores (docs/evaluation.md "Cost"); `make run SEEDS=N` for more.
SEEDS  ?= 5

.PHONY: run test test-quick lint install clean

# the bench's inner loops and the controller's kernels compiled with mypyc, beside their sources
# (dbc/runtime/compiled.py)
COMPILED := $(patsubst %,firmware_sim/%.py,encoder plant pid watchdog drive sim) controller/kernels.py
COMPILED_STAMP := $(VENV)/.compiled

$(STAMP): pyproject.toml setup.py constraints.txt
	$(PYTHON) -m venv $(VENV)
	@# pure Python here: the compiled modules are built once, below, with the venv's mypyc;
	@# the versions tested together (constraints.txt) within pyproject.toml's ranges
	WHEELCHAIR_HIL_PURE_PYTHON=1 $(BIN)/python -m pip install --quiet --no-compile \
		-c constraints.txt -e '.[bench,eval,live,dev,dask]'
	@# byte-compiled once, on both cores: where PYTHONDONTWRITEBYTECODE is set (as on these
	@# CI machines) no import writes it, and every process would compile numpy, scipy and
	@# the rest from source again ('import controller.node, tools.run.parts' 2.0-2.7 s
	@# against 1.45-1.6 s compiled; compiling takes 26 s)
	$(BIN)/python -m compileall -q -j 0 $(VENV)/lib > /dev/null
	touch $(STAMP)

# again whenever one of their sources changes (a stale one is not used: the bench then runs
# from source, with a warning); where compiling fails (no C compiler or Python headers),
# setup.py builds none of them and says so, and that line is shown here
$(COMPILED_STAMP): $(STAMP) $(COMPILED) dbc/runtime/compiled.py
	$(BIN)/python setup.py --quiet build_ext --inplace --parallel 2 > $(VENV)/compile.log 2>&1 \
		|| { cat $(VENV)/compile.log; exit 1; }
	@grep -h "WARNING: compiling failed" $(VENV)/compile.log || true
	touch $(COMPILED_STAMP)

# and the checkout's own bytecode (compileall redoes only what changed): where
# PYTHONDONTWRITEBYTECODE is set, every process would compile the stack's modules again
# ('import controller.node, tools.run.parts, tools.cli' 0.65 s against 0.58 s)
install: $(STAMP) $(COMPILED_STAMP)
	@$(BIN)/python -m compileall -q -j 0 dbc firmware_sim controller tools tests > /dev/null

run: install
	$(BIN)/wheelchair-hil evaluate --out $(OUT)/eval --seeds $(SEEDS)

lint: install
	$(BIN)/ruff check .
	$(BIN)/ruff format --check .
	$(BIN)/mypy

# make test: lint, then the lock-step tests on two workers beside the socketcan lane (a
# one-CPU user-mode Linux guest, tests/hil/test_socketcan_lane.py), then the tests that need
# the machine to themselves (marked `alone`: real time); tests/lanes.sh says how, and writes
# each part's wall time to $(OUT)/test-times.txt.  LANE=0 runs everything in one pytest.
LANE ?= 1

test: install
ifeq ($(LANE),1)
	@bash tests/lanes.sh $(BIN) $(OUT)
else
	$(MAKE) lint
	$(BIN)/python -m pytest -q
endif

# make test-quick: a few minutes for a pull request (docs/deploy.md "In a team's CI"): lint and
# type checks, the unit tests, and one lock-step run of each controller from a hard start
# and on the paper route; `make test` is the whole suite.
test-quick: install
	$(BIN)/ruff check .
	$(BIN)/ruff format --check .
	$(BIN)/mypy
	$(BIN)/python -m pytest -q -p no:cacheprovider -n 2 -m "not alone" tests/unit \
		tests/integration/test_controller_hard_starts.py tests/integration/test_closed_loop.py

clean:
	rm -rf $(VENV) $(OUT) .pytest_cache .mypy_cache .ruff_cache build firmware_sim/*.so
