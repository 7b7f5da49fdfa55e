# The two commands of the README: `make demo` and `make test` (each sets up first).
PYTHON  ?= python3
VENV    := .venv
BIN     := $(VENV)/bin
STAMP   := $(VENV)/.installed
FMUS    := fmus/build/.built
FMU_SRC := $(wildcard fmus/odometry/* fmus/wrapper/*) fmus/build.py

.PHONY: setup demo test test-fast soak bench clean

setup: $(STAMP) $(FMUS)

$(STAMP): pyproject.toml
	@test -x $(BIN)/python || $(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet -e '.[test,ros2]'
	@touch $(STAMP)

$(FMUS): $(STAMP) $(FMU_SRC)
	$(BIN)/diffbot fmu build
	@touch $(FMUS)

demo: setup
	$(BIN)/diffbot run follow --out out/demo

test: setup
	$(BIN)/python -m pytest -q

test-fast: setup
	$(BIN)/python -m pytest -q -m "not slow"

# One hour of simulated time in lockstep, sensors on (SOAK_SIM_S=600 for a shorter one):
# memory, lost messages, /dev/shm. Writes out/soak/soak.json.
soak: setup
	$(BIN)/python -m pytest -q -s -m soak -p no:cacheprovider tests/test_soak.py

bench: setup
	$(BIN)/diffbot bench

clean:
	rm -rf out fmus/build .pytest_cache
