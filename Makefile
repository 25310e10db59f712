# Every command the README shows. `make run` and `make test` set everything up by themselves.
PYTHON ?= python3
VENV ?= .venv
BIN := $(VENV)/bin
MAP ?= maps/map-1.yaml
ARGS ?=
TORCH_ARGS ?=

.PHONY: setup run test lint format type bench bench-training bench-learning bench-exhaustive bench-transfer bench-designer bench-search-ray bench-sweeps clean

# torch first: 2.13.0 is a local CPU wheel; a bare `torch` requirement would pull GBs of CUDA. Where no CPU wheel is
# at hand, TORCH_ARGS="--index-url https://download.pytorch.org/whl/cpu" takes PyTorch's CPU build.
$(BIN)/.installed: pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install -q --upgrade pip
	$(BIN)/python -m pip install -q torch==2.13.0 $(TORCH_ARGS)
	$(BIN)/python -m pip install -q -e '.[dev]'
	touch $@

setup: $(BIN)/.installed

run: setup  ## the main job: PPO on the shipped default map, on a local Ray started for it
	$(BIN)/smorphi-rl train --map $(MAP)

# 2 workers, each test file whole on one (its module fixtures built once, the README's examples in order): much of a
# Ray test is waiting, so a fresh clone's suite took 8.6 min against 11.2 on 2 cores (docs/decisions.md).
test: setup  ## lint, format check, type check and the whole suite
	$(BIN)/ruff check smorphi_rl tests scripts
	$(BIN)/ruff format --check smorphi_rl tests scripts
	$(BIN)/mypy smorphi_rl
	$(BIN)/python -m pytest -q -n 2 --dist loadfile

lint: setup
	$(BIN)/ruff check smorphi_rl tests scripts

format: setup
	$(BIN)/ruff format smorphi_rl tests scripts
	$(BIN)/ruff check --fix smorphi_rl tests scripts

type: setup
	$(BIN)/mypy smorphi_rl

bench: setup
	$(BIN)/python scripts/bench_fbcpp.py $(ARGS)

bench-training: setup
	$(BIN)/python scripts/bench_training.py $(ARGS)

bench-learning: setup
	$(BIN)/python scripts/bench_learning.py $(ARGS)

bench-exhaustive: setup
	$(BIN)/python scripts/bench_exhaustive.py $(ARGS)

bench-transfer: setup
	$(BIN)/python scripts/bench_transfer.py $(ARGS)

bench-designer: setup
	$(BIN)/python scripts/bench_designer.py $(ARGS)

bench-search-ray: setup  ## search exhaustive on a local Ray with 1 and 2 CPUs against the local pool
	$(BIN)/python scripts/bench_search_ray.py $(ARGS)

bench-sweeps: setup  ## the shipped sweep files through `smorphi-rl sweep`, timed, with their tables over seeds
	$(BIN)/python scripts/bench_sweeps.py $(ARGS)

clean:
	rm -rf $(VENV) .pytest_cache .ruff_cache .mypy_cache .hypothesis
