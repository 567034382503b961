# Two entry points (README quick start): `make demo` and `make test`.
# Both bootstrap .venv idempotently from requirements.lock (exact versions, made by
# `make lock` from the ranges in pyproject.toml); it is redone only when either changes.
PYTHON ?= python3.11
VENV   := .venv
BIN    := $(VENV)/bin
STAMP  := $(VENV)/.installed

.PHONY: demo test pytest test-fast lint bench lock clean sysdeps docs

# The emulated radio (SPEC §8) needs iproute2 and nftables, the dashboard tests (SPEC §10)
# Debian's chromium; as root on Debian the missing ones are installed here, in one
# apt-get call (CI runs as root on a fresh machine; chromium is large, so only when
# missing). Elsewhere the tests that need them say what is missing and skip.
sysdeps:
	@missing=""; \
	command -v ip >/dev/null || missing="$$missing iproute2"; \
	command -v nft >/dev/null || missing="$$missing nftables"; \
	command -v chromium >/dev/null || missing="$$missing chromium"; \
	if [ -n "$$missing" ]; then \
	  if [ "$$(id -u)" = 0 ] && command -v apt-get >/dev/null; then \
	    echo "installing$$missing (emulated radio, dashboard tests)"; \
	    apt-get update -qq >/dev/null && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq $$missing >/dev/null; \
	  else echo "note: missing$$missing: the emulated-radio tests (iproute2, nftables) and dashboard tests (chromium) will skip (or fail in CI)"; fi; \
	fi

# uv (pinned in the lock) installs it about 4x faster than pip: 13 s against 47 s from
# cold caches on the 2-core CI machine. If uv cannot (say, only a pip mirror is
# reachable: uv does not read pip.conf), pip does the same from the same lock.
# Python may write bytecode: in an environment exporting PYTHONDONTWRITEBYTECODE=1 (the
# image of this 2-core VM does), every `fleet` process and every pytest worker compiled
# its imports again, half of a process's start (0.7 s of CPU against 0.3 s for the
# ground's imports) and a sixth of the suite's CPU (ADR 0011). Nothing is compiled at
# install: uv's --compile-bytecode compiled all 900 MB of the venv, 15 of the 16 s an
# install took, before the first test could start; `make pytest` compiles what the
# suite imports by collecting it once.
# A venv from before the package was renamed (ADR 0012) still holds the old `fleet`
# distribution: it is removed first, or its finder would serve stale modules.
UV_PIN := $(shell sed -n 's/^uv==//p' requirements.lock)
unexport PYTHONDONTWRITEBYTECODE

$(STAMP): pyproject.toml requirements.lock
	@test -x $(BIN)/python || $(PYTHON) -m venv $(VENV)
	@echo "installing requirements.lock into $(VENV)"
	@if $(BIN)/python -m pip install --quiet --disable-pip-version-check uv==$(UV_PIN) 2>/dev/null \
	    && { $(BIN)/uv pip uninstall --quiet --python $(BIN)/python fleet 2>/dev/null; true; } \
	    && $(BIN)/uv pip install --quiet --python $(BIN)/python -r requirements.lock \
	    && $(BIN)/uv pip install --quiet --python $(BIN)/python --no-deps -e .; then :; else \
	  echo "uv could not install the lock; installing it with pip"; \
	  $(BIN)/python -m pip install --quiet --upgrade pip \
	    && $(BIN)/python -m pip install --quiet -r requirements.lock \
	    && $(BIN)/python -m pip install --quiet --no-deps -e .; \
	fi
	@touch $(STAMP)

# Resolve the ranges of pyproject.toml (every extra and the tests) to exact versions.
lock: $(STAMP)
	$(BIN)/python -m pip install --quiet uv
	$(BIN)/uv pip compile pyproject.toml --extra test --python-version 3.11 \
	  --python-platform x86_64-unknown-linux-gnu --upgrade -o requirements.lock

demo: $(STAMP)
	$(BIN)/fleet demo $(ARGS)

# Eight workers on the 2 cores: many tests wait on real time (drones flying), and eight
# keep both cores busy 81-88 % of a run (ten: 94 %, and no faster: ADR 0011).
# `--dist loadgroup` hands out work units: the groups first (the Chromium tests; the radio
# tests of each of the two radio slots; the modules sharing a fleet), then single tests
# longest first (the `slow` marker, tests/conftest.py); a worker gets another unit when it
# has two tests or fewer left (ADR 0011). Each run prints its 25 slowest tests.
# The lint runs beside the tests (13 s of mypy and friends) at the lowest CPU priority:
# it takes the cores while the tests wait on flying drones, not while workers start.
# Either failing fails it.
test: $(STAMP) sysdeps
	@$(MAKE) --no-print-directory -j2 LINT_PRIORITY="nice -n 19" lint pytest

# Collected once first: the workers then find every test module's assertions rewritten
# and every module the suite imports (1800, most of what a `fleet` process imports too)
# compiled: each worker's collection takes 2.2 CPU-seconds instead of 4.2 in a fresh
# clone. Two processes collect half the test folders each, on both cores (7 s instead of
# 9 in a fresh clone; what both import is compiled twice at most). A collection error is
# reported by the run that follows.
pytest: $(STAMP)
	@half=0; one=""; other=""; for t in tests/[!_]*/ tests/test_*.py; do \
	  if [ $$half = 0 ]; then one="$$one $$t"; half=1; else other="$$other $$t"; half=0; fi; done; \
	$(BIN)/python -m pytest -qq --collect-only -p no:cacheprovider $$one > /dev/null 2>&1 & \
	$(BIN)/python -m pytest -qq --collect-only -p no:cacheprovider $$other > /dev/null 2>&1; wait; true
	$(BIN)/python -m pytest -q -n 8 --dist loadgroup

# The documentation site into site/ (mkdocs-material; the suite builds it with --strict).
docs: $(STAMP)
	NO_MKDOCS_2_WARNING=1 $(BIN)/mkdocs build --strict --site-dir site

# ruff, mypy and the layer contracts (import-linter), configured in pyproject.toml.
lint: $(STAMP)
	$(LINT_PRIORITY) $(BIN)/ruff check .
	$(LINT_PRIORITY) $(BIN)/mypy
	$(LINT_PRIORITY) $(BIN)/lint-imports

# Pure logic and virtual-time tests only: seconds, no processes, no sockets.
test-fast: $(STAMP)
	$(BIN)/python -m pytest -q -n 2 -m "not integration"

bench: $(STAMP)
	$(BIN)/python bench/agent_install.py
	$(BIN)/python bench/agent_cpu.py
	$(BIN)/python bench/agent_mavsdk.py
	$(BIN)/python bench/autopilot_contract.py --autopilot sim-px4 --runs 1  # FLEET_PX4_BUILD / FLEET_ARDUCOPTER: real SITLs
	$(BIN)/python bench/ground_fanin.py
	$(BIN)/python bench/ground_command.py
	$(BIN)/python bench/bundles.py
	$(BIN)/python bench/mission_sim.py
	$(BIN)/python bench/mission_process.py
	$(BIN)/python bench/recording.py
	$(BIN)/python bench/security.py
	$(BIN)/python bench/dashboard_frames.py
	$(BIN)/python bench/zenoh_modes.py
	$(BIN)/python bench/relay_experiments.py
	$(BIN)/python bench/relay_hop.py --seeds 2
	$(BIN)/python bench/relay_corpus.py --worlds 4
	$(BIN)/python bench/mesh.py  # needs CAP_NET_ADMIN (root), as fleet sim --radio
	$(BIN)/python bench/mesh_stall.py --runs 1  # root too
	$(BIN)/python bench/link_flyout.py --runs 2  # root too
	$(BIN)/python bench/mesh_corpus.py --scenarios 3  # root too
	$(BIN)/python bench/relay_real_packets.py  # root too; 5 min
	$(BIN)/python bench/no_ground_flight.py --minutes 1
	$(BIN)/python bench/example_hashes.py  # the bytes each example writes (compare before/after a refactoring)

clean:
	rm -rf $(VENV) .pytest_cache build *.egg-info
