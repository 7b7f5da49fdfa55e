# The two commands of the README: `make demo` and `make test` (each sets up first).
PYTHON  ?= python3
VENV    := .venv
BIN     := $(VENV)/bin
STAMP   := $(VENV)/.installed
FMUS    := fmus/build/.built
TF2MSGS := $(VENV)/share/tf2_msgs/diffbot-build.txt
FMU_SRC := $(wildcard fmus/odometry/* fmus/wrapper/*) fmus/build.py
# the plant's C kernels (lidar, camera): plant/kernels/build/, and the controllers'
# (controllers/kernels/build/), loaded with ctypes
KERNELS := plant/kernels/build/.built
KERNEL_SRC := $(wildcard plant/kernels/*.c plant/kernels/*.h controllers/kernels/*.c controllers/kernels/*.h) plant/kernels/build.py plant/kernels/__init__.py

.PHONY: setup demo test test-random test-fast soak bench clean netns-tools

setup: $(STAMP) $(FMUS) $(KERNELS) $(TF2MSGS)

# INSTALLER=uv (the default): uv, itself from PyPI, installs into the venv the packages pip
# would (the same versions), with .pyc compiled, in a third of pip's time (docs/install.md).
# uv reads no pip.conf: INSTALLER=pip for an index or constraints set up for pip only.
INSTALLER ?= uv
# The sb3 extra (Stable-Baselines3) needs torch, installed first: a CPU build, where an
# index's plain torch is a CUDA build of several GB. A CPU wheel of that version in pip's
# find-links folder ($PIP_FIND_LINKS: this machine keeps one) is installed by uv (~11 s, ~800
# MB in the venv); otherwise pip installs $(TORCH) as its configuration finds it (~30 s
# here). uv then finds torch installed. `make setup TORCH=` leaves torch and the sb3 extra
# out (their tests then skip, saying so).
TORCH     ?= torch==2.13.0
TORCH_WHEEL = $(firstword $(wildcard $(PIP_FIND_LINKS)/$(subst ==,-,$(TORCH))+cpu-*.whl))
comma     := ,
EXTRAS    := .[test,view,ros2,cluster,learn$(if $(TORCH),$(comma)sb3)]
$(STAMP): pyproject.toml tests/js/package-lock.json
	@test -x $(BIN)/python || $(PYTHON) -m venv $(VENV)
ifeq ($(INSTALLER),uv)
	$(BIN)/python -m pip install --quiet 'uv>=0.5'
ifneq ($(TORCH),)
	@w='$(TORCH_WHEEL)'; if [ -n "$$w" ] && $(BIN)/uv pip install --quiet --python $(BIN)/python \
	   --compile-bytecode "$$w"; then echo "torch: $$w"; \
	 else $(BIN)/python -m pip install --quiet '$(TORCH)'; fi
endif
	$(BIN)/uv pip install --quiet --python $(BIN)/python --compile-bytecode -e '$(EXTRAS)'
else
ifneq ($(TORCH),)
	$(BIN)/python -m pip install --quiet '$(TORCH)'
endif
	$(BIN)/python -m pip install --quiet -e '$(EXTRAS)'
endif
	@touch $(STAMP)
	@# The live view's tests drive it with the real Foxglove JS client (Node >= 18)
	@if command -v npm >/dev/null; then (cd tests/js && npm ci --silent --no-audit --no-fund) \
	   || echo "npm ci failed: the Foxglove client tests will be skipped"; \
	 else echo "npm not found: the Foxglove client tests will be skipped"; fi

# tf2_msgs/msg/TFMessage for rclpy (/tf over ROS 2): generated with the PyPI rosidl
# generators and compiled into the venv (docs/ros2.md). Without it the bridge runs, without /tf.
$(TF2MSGS): $(STAMP) bridges/ros2_msgs.py
	@$(BIN)/python -m bridges.ros2_msgs || echo "(make setup goes on without tf2_msgs)"

$(FMUS): $(STAMP) $(FMU_SRC)
	$(BIN)/diffbot fmu build
	@touch $(FMUS)

$(KERNELS): $(STAMP) $(KERNEL_SRC)
	$(BIN)/python -m plant.kernels.build
	$(BIN)/python -m plant.kernels.build --src controllers/kernels --out controllers/kernels/build --name libcontroller_kernels
	@touch $(KERNELS)

demo: setup
	$(BIN)/diffbot run follow --out out/demo

# As CI runs it: CI set (a missing FMU or tool fails instead of skipping; Hypothesis
# derandomised, fewer examples: tests/conftest.py) unless the environment says otherwise.
# On TEST_WORKERS pytest-xdist workers: a file's tests on one worker, the tests marked
# `serial` (wall-clock promises, machine-wide state) alone (tests/conftest.py).
# Three workers (the default) on two cores: the suite's tests wait more than they compute
# (leases, lockstep turns, process start-ups), and a third fills those waits: 358-368 s of
# tests against 442 s with two (docs/install.md); TEST_WORKERS=0: one process, as plain `pytest`.
TEST_WORKERS ?= 3
test: setup netns-tools
	CI=$${CI:-true} $(BIN)/python -m pytest -q -n $(TEST_WORKERS) --dist loadgroup --no-loadscope-reorder

# The whole suite in an order shuffled by pytest-randomly (no test may need another to run
# first), as `make test` otherwise: SEED=N repeats an order (default: a new one, printed).
SEED ?= $(shell date +%s)
test-random: setup netns-tools
	@echo "test order: --randomly-seed=$(SEED)"
	CI=$${CI:-true} $(BIN)/python -m pytest -q -p randomly --randomly-seed=$(SEED) \
	  -n $(TEST_WORKERS) --dist loadgroup

# tests/network/test_netns.py needs `ip` (iproute2) and `openssl`, the Ecos runs of tests/fmus/test_plant_fmu.py
# libtbb.so.12 (libtbb12). Installed only when missing,
# only as root, only with apt-get (a fresh Debian CI machine); otherwise the test skips
# and says why.
netns-tools:
	@if [ "$$(id -u)" = 0 ] && command -v apt-get >/dev/null && \
	    { ! command -v ip >/dev/null || ! command -v openssl >/dev/null || \
	      ! ldconfig -p | grep -q libtbb.so.12; }; then \
	  echo "installing iproute2 and openssl (tests/network/test_netns.py), libtbb12 (Ecos, tests/fmus/test_plant_fmu.py)"; \
	  apt-get update -qq && apt-get install -y -qq iproute2 openssl >/dev/null; \
	  apt-get install -y -qq libtbb12 >/dev/null || echo "no libtbb12: the Ecos tests will skip"; fi

test-fast: setup
	$(BIN)/python -m pytest -q -m "not slow"

# One hour of simulated time in lockstep, sensors on (SOAK_SIM_S=600 for a shorter one):
# memory, lost messages, /dev/shm. Writes out/soak/soak.json.
soak: setup
	$(BIN)/python -m pytest -q -s -m soak -p no:cacheprovider tests/runs/test_soak.py

bench: setup
	$(BIN)/diffbot bench

clean:
	rm -rf out fmus/build plant/kernels/build controllers/kernels/build .pytest_cache build dist *.egg-info
