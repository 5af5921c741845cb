# graft: `make demo` trains TD3 on Pendulum through a local Ray cluster; `make test` runs the tests.
# Both set everything up first (virtual environment, CPU torch on CPU-only machines, the package).
PYTHON ?= $(shell command -v python3.11 || command -v python3)
VENV   ?= .venv
BIN    := $(VENV)/bin
TORCH  := 2.13.0

.PHONY: demo test test-fast test-long setup lint proto proto-check bench clean

demo: setup
	$(BIN)/graft train --preset pendulum-td3

# The user-task fixture and each example project are packages of their own, installed the
# way a user installs theirs.
TEST_PACKAGES := $(VENV)/.usertask $(VENV)/.example-mountaincar $(VENV)/.example-cartpole
# The suite mostly waits (Ray and servers starting, real-time clocks), so it runs on more
# xdist workers than cores, a file per worker (a module's shared server or cluster stays on
# one); tests that measure real-time pacing, or reuse a port across a restart, run after it.
TEST_WORKERS ?= 4

# Every test: the parallel part, then the real-time part.
test: setup $(TEST_PACKAGES)
	$(BIN)/python -m pytest -q -n $(TEST_WORKERS) --dist loadfile -m "not serial and not long"
	$(BIN)/python -m pytest -q -m "serial and not long"

# The inner loop: no Ray, no server processes (starting either fails the test here).
test-fast: setup $(TEST_PACKAGES)
	GRAFT_TEST_FAST=1 $(BIN)/python -m pytest -q -n 2 -m "not service and not slow and not serial and not long"

# Checks too long for `make test` (a C++ build of compiled kernels); CI runs them too.
test-long: setup $(TEST_PACKAGES)
	$(BIN)/python -m pytest -q -m long

$(VENV)/.usertask: tests/fixtures/usertask/pyproject.toml $(VENV)/.installed
	$(BIN)/pip install --no-deps -e tests/fixtures/usertask
	touch $@

$(VENV)/.example-%: examples/%/pyproject.toml $(VENV)/.installed
	$(BIN)/pip install --no-deps -e examples/$*
	touch $@

setup: $(VENV)/.installed

$(VENV)/.installed: pyproject.toml
	$(PYTHON) -m venv $(VENV)
	@# Never pull multi-GB CUDA wheels onto a machine without a GPU.
	@if command -v nvidia-smi >/dev/null 2>&1; then \
		$(BIN)/pip install "torch==$(TORCH)"; \
	else \
		$(BIN)/pip install "torch==$(TORCH)+cpu" 2>/dev/null || \
		$(BIN)/pip install --index-url https://download.pytorch.org/whl/cpu "torch==$(TORCH)+cpu"; \
	fi
	$(BIN)/pip install -e ".[dev]"
	touch $@

lint: setup
	$(BIN)/ruff check .
	$(BIN)/ruff format --check .
	$(BIN)/mypy service actors learner graft
	$(BIN)/lint-imports

# Generated gRPC code is checked in; CI regenerates it and fails on drift.
proto: setup
	$(BIN)/python -m grpc_tools.protoc -Iservice/replay/_proto=protos/graft/replay/v1 \
		--python_out=. --grpc_python_out=. --pyi_out=. protos/graft/replay/v1/replay.proto

proto-check: proto
	git diff --exit-code -- service/replay/_proto

bench: setup
	$(BIN)/python bench/replay.py
	$(BIN)/python bench/pendulum.py

clean:
	rm -rf $(VENV) runs .pytest_cache
