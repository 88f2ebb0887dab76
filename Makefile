# Two commands for a newcomer: `make demo` and `make test`. Both set everything up first.
PYTHON ?= python3
VENV   := .venv
BIN    := $(VENV)/bin
STAMP  := $(VENV)/.installed
APT_PACKAGES := povray libllvm19

.PHONY: setup system demo test lint format bench goldens clean

setup: system $(STAMP)

# System packages: installed when we are root, otherwise the exact command is printed and we stop.
system:
	@sh tools/system-deps.sh $(APT_PACKAGES)

$(STAMP): pyproject.toml
	@$(PYTHON) -c 'import sys; sys.exit(0 if sys.version_info >= (3, 11) else "minirt needs Python >= 3.11")'
	$(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip
	$(BIN)/python -m pip install --quiet -e '.[dev]'
	@touch $(STAMP)

demo: setup
	$(BIN)/minirt render scenes/exercise.toml --backend all --out renders/exercise

test: setup
	$(BIN)/ruff check minirt oracles tests benchmarks
	$(BIN)/ruff format --check minirt oracles tests benchmarks
	$(BIN)/python -m pytest

lint:
	$(BIN)/ruff check minirt oracles tests benchmarks

format:
	$(BIN)/ruff format minirt oracles tests benchmarks
	$(BIN)/ruff check --fix minirt oracles tests benchmarks

# Refresh the reference tracer's golden images on purpose (after an intended change to its output).
goldens: setup
	MINIRT_UPDATE_GOLDENS=1 $(BIN)/python -m pytest -q tests/test_goldens.py

bench: setup
	$(BIN)/python benchmarks/bench.py

clean:
	rm -rf $(VENV) renders out .pytest_cache
