# graft: `make demo` trains TD3 on Pendulum through a local Ray cluster; `make test` runs the tests.
# Both set everything up first (virtual environment, CPU torch on CPU-only machines, the package).
PYTHON ?= $(shell command -v python3.11 || command -v python3)
VENV   ?= .venv
BIN    := $(VENV)/bin
TORCH  := 2.13.0
comma  := ,

.PHONY: demo test test-fast test-long test-lowest test-wheel test-containers dist image setup lint proto proto-check bench clean

demo: setup
	$(BIN)/graft train --preset pendulum-td3

# The user-task fixture and each example project are packages of their own, installed the
# way a user installs theirs.
TEST_PACKAGES := $(VENV)/.usertask $(VENV)/.example-mountaincar $(VENV)/.example-cartpole \
	$(VENV)/.example-lunarlander $(VENV)/.example-halfcheetah $(VENV)/.example-heldout
# The suite is CPU-bound on 2 cores: two xdist workers (more cost CPU in contention than
# they save in waits), a file per worker (a module's shared server or cluster stays on one).
# Tests that measure real-time pacing, or reuse a port across a restart, are marked
# `serial`: they run beside the parallel part, in one process, at normal priority while
# the parallel part is niced, so they get a core when they ask for one.
TEST_WORKERS ?= 2
TEST_DIST ?= loadfile
TEST_SELECT := not long and not wheel and not container
# Tests run with bytecode written, graft's own compiled first (a second), where
# PYTHONDONTWRITEBYTECODE is set (as on the 2-core machine): otherwise every process the
# suite starts compiles graft's modules from source (a replay server starts in 0.48 s
# of CPU against 0.43 s, bench/compiled_starts.py) and pytest rewrites every test
# module's asserts again in each process and run (`make test-fast` again: 44.7 s of CPU
# against 42.5 s).
PYTEST := env -u PYTHONDONTWRITEBYTECODE $(BIN)/python -m pytest
COMPILE := env -u PYTHONDONTWRITEBYTECODE $(BIN)/python -m compileall -q -j 0 \
	graft service actors minecraft learner examples tests bench > /dev/null

# Every test: the parallel part, with the real-time part beside it (its log printed after).
test: setup $(TEST_PACKAGES)
	@$(COMPILE)
	@log=$$(mktemp); \
	$(PYTEST) -q -p no:cacheprovider -m "serial and $(TEST_SELECT)" > $$log 2>&1 & serial=$$!; \
	nice -n 10 $(PYTEST) -q -n $(TEST_WORKERS) --dist $(TEST_DIST) -m "not serial and $(TEST_SELECT)"; parallel=$$?; \
	wait $$serial; real_time=$$?; \
	echo "--- the real-time part (serial tests, run beside it):"; \
	if [ $$real_time -eq 0 ]; then tail -n 1 $$log; else cat $$log; fi; rm -f $$log; \
	[ $$parallel -eq 0 ] && [ $$real_time -eq 0 ]

# The inner loop: no Ray, no server processes (starting either fails the test here).
test-fast: setup $(TEST_PACKAGES)
	GRAFT_TEST_FAST=1 $(PYTEST) -q -n 2 -m "not service and not slow and not serial and not long"

# Checks too long for `make test` (a C++ build of compiled kernels; a three-node Ray cluster
# in network namespaces, as root); CI runs them too.
test-long: setup $(TEST_PACKAGES)
	@$(COMPILE)
	$(PYTEST) -q -m long

$(VENV)/.usertask: tests/fixtures/usertask/pyproject.toml $(VENV)/.installed
	$(BIN)/pip install --no-deps -e tests/fixtures/usertask
	touch $@

$(VENV)/.example-%: examples/%/pyproject.toml $(VENV)/.installed
	$(BIN)/pip install --no-deps -e examples/$*
	touch $@

# The wheel as a user gets it: built, installed into a fresh venv, `graft presets` and a
# 1,500-step pendulum-td3 (minutes: tests/deploy/test_wheel.py).
test-wheel: setup
	$(BIN)/python -m pytest -q tests/deploy/test_wheel.py

# The lowest versions pyproject.toml allows: each dependency pinned to its floor, then a
# 1,500-step pendulum-td3 (Ray, the replay server over gRPC, TensorBoard) and the quick
# subset of the replay and learner tests. torch stays at $(TORCH): the CPU build of its
# floor is not on PyPI.
LOWEST ?= .venv-lowest
test-lowest:
	rm -rf $(LOWEST)
	$(PYTHON) -m venv $(LOWEST)
	$(call install_torch,$(LOWEST)/bin)
	$(PYTHON) .ci/lowest_constraints.py --hold torch > $(LOWEST)/constraints.txt
	$(LOWEST)/bin/pip install --only-binary :all: -c $(LOWEST)/constraints.txt \
		. pytest pytest-timeout pytest-xdist
	cd $(LOWEST) && env -u PYTHONPATH -u RAY_ADDRESS bin/graft train --preset pendulum-td3 \
		--env-steps 1500 --actors 1 --address local --run-dir run --no-progress
	env -u PYTHONPATH $(LOWEST)/bin/python -m pytest -q -n 2 \
		-m "not service and not slow and not serial and not long" tests/service/replay tests/learner

# A cluster in containers of the image IMAGE (which must exist: make image): a head and two
# workers on a bridge network, the runs of tests/deploy/test_containers.py (minutes). CI runs
# it through .ci/containers.sh, which starts dockerd, builds the image and cleans up.
CONTAINER_LABEL ?=
test-containers: setup
	GRAFT_IMAGE=$(IMAGE) DOCKER=$(DOCKER) GRAFT_CONTAINER_LABEL=$(CONTAINER_LABEL) \
		$(BIN)/python -m pytest -q -m container tests/deploy/test_containers.py

# An sdist and a wheel in dist/.
dist: setup
	$(BIN)/python -m build

# The image of deploy/Dockerfile. BASE: an official Python image, or the local one
# deploy/make-base.sh makes where no registry answers. CA: the bundle pip trusts while
# building (a BuildKit secret, never in a layer); empty for the base's own.
IMAGE  ?= graft:latest
BASE   ?= python:3.11-slim
CA     ?= $(wildcard /etc/ssl/certs/ca-certificates.crt)
DOCKER ?= docker
image:
	@$(DOCKER) image inspect $(BASE) >/dev/null 2>&1 || $(DOCKER) pull -q $(BASE) >/dev/null 2>&1 \
		|| { echo "make image: BASE=$(BASE) is neither a local image nor pullable (deploy/make-base.sh makes one)" >&2; exit 2; }
	@[ -z "$(CA)" ] || [ -s "$(CA)" ] || { echo "make image: CA=$(CA): no such file" >&2; exit 2; }
	@# The CPU torch wheel pip finds here (its config's find-links), for a build that cannot
	@# reach download.pytorch.org; the build bind-mounts deploy/wheels/ and never copies it.
	@mkdir -p deploy/wheels
	-@$(PYTHON) -m pip download -q --no-deps -d deploy/wheels "torch==$(TORCH)+cpu" 2>/dev/null
	DOCKER_BUILDKIT=1 $(DOCKER) build -f deploy/Dockerfile -t $(IMAGE) --build-arg BASE=$(BASE) \
		--build-arg TORCH=$(TORCH) $(if $(CA),--secret id=ca$(comma)src=$(CA)) .

setup: $(VENV)/.installed

# Never pull multi-GB CUDA wheels onto a machine without a GPU.
define install_torch
	@if command -v nvidia-smi >/dev/null 2>&1; then \
		$(1)/pip install "torch==$(TORCH)"; \
	else \
		$(1)/pip install "torch==$(TORCH)+cpu" 2>/dev/null || \
		$(1)/pip install --index-url https://download.pytorch.org/whl/cpu "torch==$(TORCH)+cpu"; \
	fi
endef

$(VENV)/.installed: pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(call install_torch,$(BIN))
	$(BIN)/pip install -e ".[dev,bench]"
	touch $@

lint: setup
	$(BIN)/ruff check .
	$(BIN)/ruff format --check .
	$(BIN)/mypy service actors minecraft learner graft
	$(BIN)/lint-imports

# Generated gRPC code is checked in; CI regenerates it and fails on drift. A copy of the proto
# sits beside it, at the path its descriptors name, so that the wheel carries it.
proto: setup
	$(BIN)/python -m grpc_tools.protoc -Iservice/replay/_proto=protos/graft/replay/v1 \
		--python_out=. --grpc_python_out=. --pyi_out=. protos/graft/replay/v1/replay.proto
	cp protos/graft/replay/v1/replay.proto service/replay/_proto/replay.proto

proto-check: proto
	git diff --exit-code -- service/replay/_proto

bench: setup
	$(BIN)/python bench/replay.py
	$(BIN)/python bench/pendulum.py

clean:
	rm -rf $(VENV) $(LOWEST) dist deploy/wheels runs .pytest_cache
