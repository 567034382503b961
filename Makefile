# Two entry points (README quick start): `make demo` and `make test`.
# Both bootstrap .venv idempotently: it is rebuilt only when pyproject.toml changes.
PYTHON ?= python3.11
VENV   := .venv
BIN    := $(VENV)/bin
STAMP  := $(VENV)/.installed

.PHONY: demo test bench clean

$(STAMP): pyproject.toml
	@test -x $(BIN)/python || $(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip
	$(BIN)/python -m pip install --quiet -e '.[test]'
	@touch $(STAMP)

demo: $(STAMP)
	$(BIN)/fleet demo $(ARGS)

test: $(STAMP)
	$(BIN)/python -m pytest -q

bench: $(STAMP)
	$(BIN)/python bench/agent_cpu.py
	$(BIN)/python bench/agent_mavsdk.py
	$(BIN)/python bench/ground_fanin.py
	$(BIN)/python bench/ground_command.py
	$(BIN)/python bench/mission_sim.py

clean:
	rm -rf $(VENV) .pytest_cache build *.egg-info
