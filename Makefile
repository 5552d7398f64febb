# Two entry points a new user types: `make train` and `make test`.
# Both create the virtual environment and install the project on first use.
PYTHON ?= python3
VENV ?= .venv
PY := $(VENV)/bin/python
STAMP := $(VENV)/.installed

.PHONY: install train test lint docs bench figures

install: $(STAMP)

# The exact tested set (constraints/tested.txt) within pyproject.toml's ranges.
$(STAMP): pyproject.toml constraints/tested.txt
	$(PYTHON) -m venv $(VENV)
	$(PY) -m pip install --quiet -c constraints/tested.txt -e ".[dev]"
	touch $(STAMP)

# The main job: A2C + VAE surprise on a MiniGrid task, a few minutes on 2 CPU cores.
train: $(STAMP)
	$(PY) recipes/minigrid/main.py eval.video=true $(ARGS)

# The suite on TEST_WORKERS processes (pytest-xdist; 2 for the project's 2-core
# machine; TEST_WORKERS=0 runs it in one process), an idle worker taking queued
# tests from a busy one (the recipe tests take seconds, most others milliseconds);
# the 15 slowest tests are listed.
TEST_WORKERS ?= 2
test: $(STAMP)
	$(PY) -m ruff check .
	$(PY) -m ruff format --check .
	$(PY) -m pytest -n $(TEST_WORKERS) --dist worksteal --durations=15 $(ARGS)

docs: $(STAMP)
	$(PY) -m sphinx -W --keep-going -b html docs docs/_build/html

# Every table and figure of docs/results recomputed from the committed per-run data
# (each experiment's runs.csv.xz, each heatmap summary's rows per run and layout; no
# run directory or checkpoint needed), then the suite's table from its tasks' (3 seeds
# make the full pass of the tasks whose budgets make 5 unaffordable: docs/results.rst).
SUITE_DIRS = $(filter-out %_16x128/ %_64x32/,$(wildcard docs/results/suite_*/))
figures: $(STAMP)
	$(PY) recipes/results/aggregate.py --all docs/results
	$(PY) recipes/results/suite.py $(SUITE_DIRS) --task-min-seeds KeyCorridorS6R3=3 \
		--task-min-seeds ObstructedMaze-1Dlhb=3 --task-min-seeds ObstructedMaze-2Dlhb=3 \
		--published docs/results/suite_published.csv --out docs/results/suite
	for rows in docs/results/heatmaps/*_layouts.csv.xz; do \
		$(PY) recipes/results/heatmap.py --from-layouts $$rows || exit 1; \
	done

# The speed targets, one table of side-by-side ratios (benchmarks/README.md);
# installs the optional `bench` extra (the peer, torch-ac) first. ARGS=--quick: smoke run.
bench: $(STAMP)
	$(PY) -m pip install --quiet -c constraints/tested.txt -e ".[dev,bench]"
	$(PY) benchmarks/bench_speed.py $(ARGS)
