# Two entry points (see README): `make demo` and `make test`.
PY ?= python3
VENV ?= .venv
BIN := $(VENV)/bin

.PHONY: setup demo test lint clean notebooks

setup: $(VENV)/.installed

$(VENV)/.installed: pyproject.toml
	$(PY) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip
	$(BIN)/python -m pip install --quiet -e '.[test]'
	touch $@

# The main job on the bundled fixtures.
demo: setup
	MPLBACKEND=Agg bash scripts/demo.sh $(BIN)

# Execute every notebook at full size; executed copies in out/notebooks/.
notebooks: setup
	$(BIN)/python scripts/run_notebooks.py --force

lint: setup
	$(BIN)/ruff check .

# Two workers: the tests are single-threaded JAX loops, and this machine has two cores.
# They share compiled programs through a cache in the environment's folder (fresh with
# a fresh environment, as in .ci/run); STICKSLIP_CACHE_DIR=off in the environment, or
# `make test TEST_CACHE=off`, compiles everything in each worker.
TEST_CACHE ?= $(or $(STICKSLIP_CACHE_DIR),$(abspath $(VENV))/jax-cache)
test: setup lint
	STICKSLIP_CACHE_DIR=$(TEST_CACHE) MPLBACKEND=Agg $(BIN)/python -m pytest -q -n 2 --dist loadgroup

clean:
	rm -rf $(VENV) out .pytest_cache .ruff_cache
