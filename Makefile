# Two commands set up a fresh machine (see README): `make demo` and `make test`.
VENV ?= .venv
PYTHON ?= python3
BIN := $(VENV)/bin
export PYTHON VENV

.PHONY: setup demo test test-all lint format bench tables view-picture clean

setup:
	@bash scripts/setup.sh

## Set up, generate a synthetic sequence and compare baselines on it (no dataset needed).
demo: setup
	$(BIN)/vcr-odom demo

## Set up and run the fast test suite (what CI runs).
test: setup
	$(BIN)/python -m pytest -q -m "not slow"

test-all: setup
	$(BIN)/python -m pytest -q

lint: setup
	$(BIN)/ruff check . && $(BIN)/ruff format --check .

format: setup
	$(BIN)/ruff format . && $(BIN)/ruff check --fix .

## Rerun the benchmarks behind the generated tables of README.md, docs/benchmarks.md and docs/scaling.md (hours on 2 cores).
tables: setup
	$(BIN)/python benchmarks/regenerate_tables.py --work runs/tables

## Remake the README's 3-D picture, docs/view.png: a synthetic loop drive mapped, then `vcr-odom view
## --screenshot` off-screen (no display needed; about 2 minutes on 2 cores).
view-picture: setup
	bash scripts/view_picture.sh

clean:
	rm -rf $(VENV) .pytest_cache .ruff_cache *.egg-info
