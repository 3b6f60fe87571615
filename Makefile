# Two entry points for a fresh machine: `make demo` (the main job) and `make test` (the suite and the docs).
# Both create or reuse .venv, install the CPU build of torch first (a bare `torch` requirement would
# pull a multi-GB CUDA build), then the project with its dev extra, then bmdal_reg (the `lcmd` strategy)
# with --no-deps: its selection code needs torch, numpy and dill only, while its install_requires pull
# its benchmark's openml, seaborn, mat4py and more (pyproject.toml says the same).
PYTHON ?= python3
# No pip cache: a fresh machine installs once, and the cache would double the ~2 GB the venv takes on disk.
export PIP_NO_CACHE_DIR := 1
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed

.PHONY: setup demo demo-cold demo-limit test test-fast lint clean

$(STAMP): pyproject.toml
	test -x $(BIN)/python || $(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip
	$(BIN)/python -m pip install --quiet torch==2.13.0 || \
		$(BIN)/python -m pip install --quiet torch --index-url https://download.pytorch.org/whl/cpu
	$(BIN)/python -m pip install --quiet -e '.[dev]'
	$(BIN)/python -m pip install --quiet --no-deps bmdal_reg==3.0.2 dill==0.4.1
	touch $(STAMP)

setup: $(STAMP)

# The main job: uniform, max_epistemic and auto extending a model to the whole operating domain (a warm
# start), 3 seeds each, tracked in the embedded SQLite MLflow store (mlruns/mlflow.db). Each run gets
# its own output directory. `make demo-cold` is the cold-start comparison on the skidpad grid.
demo: setup
	$(BIN)/activelearn compare experiments/configs/demo.toml --strategies uniform,max_epistemic,auto \
		--seeds 3 --workers 2 --out runs/demo/$$(date +%Y%m%d-%H%M%S)

demo-cold: setup
	$(BIN)/activelearn compare experiments/configs/demo_cold.toml --strategies uniform,max_epistemic \
		--seeds 3 --workers 2 --out runs/demo-cold/$$(date +%Y%m%d-%H%M%S)

# At the handling limit (issue 57): the 1:10 racing car from a cold start on its dynamic core, uniform
# against regressor_maximin (greedy maximin in the model's own regressor space), 2 seeds each, on the
# nominal car (where regressor_maximin ends a third lower) and on its twin (less grip, a weaker motor:
# where it ends 70 % higher). Both comparisons in MLflow.
demo-limit: setup
	out=runs/demo-limit/$$(date +%Y%m%d-%H%M%S); for car in dynamics_f1tenth dynamics_f1tenth_twin; do \
		$(BIN)/activelearn compare experiments/configs/$$car.toml --strategies uniform,regressor_maximin \
			--seeds 2 --workers 2 --out $$out/$$car || exit 1; done

# The documentation is part of the test: a broken link or a page missing from mkdocs.yml's nav fails it.
# Three pytest-xdist workers, a test file each at a time (a file's fixtures are built once): much of the
# suite waits on servers and subprocesses, so a third worker pays even on 2 cores (measured: 11.4 min
# with three, 11.5 with four; 13-15 min on 2026-12-03's slower host with every cache cold, as CI
# starts). The files go in the order tests/conftest.py gives them (the longest first; xdist would
# otherwise sort them by test count).
PYTEST := $(BIN)/python -m pytest -q -n 3 --dist loadfile --no-loadscope-reorder
# mkdocs without --quiet: it hides the warnings that --strict counts (a broken anchor then passed)
test: setup
	$(BIN)/ruff check .
	$(PYTEST)
	NO_MKDOCS_2_WARNING=1 $(BIN)/mkdocs build --strict --site-dir site

# The loop to run while working: everything but the tests marked slow (servers, racing processes, many
# campaigns, the benchmarks' quick modes); `make test` still runs them all.
test-fast: setup
	$(BIN)/ruff check .
	$(PYTEST) -m "not slow"

lint: setup
	$(BIN)/ruff check .

clean:
	rm -rf $(VENV) out site .pytest_cache .ruff_cache .hypothesis
