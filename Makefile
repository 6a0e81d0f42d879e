# Two entry points (see README): `make demo` and `make test`. Both set up .venv first.
PYTHON ?= python3.11
VENV   := .venv
BIN    := $(VENV)/bin
OUT    ?= out/demo

.PHONY: setup demo test test-slow lint clean xodr-readers

# CPU torch first, from a pinned version: a bare `torch` would pull a multi-GB CUDA build.
$(BIN)/coster-sumo: pyproject.toml
	test -x $(BIN)/python || $(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install -q --upgrade pip
	$(BIN)/python -m pip install -q torch==2.13.0
	$(BIN)/python -m pip install -q -e '.[dev]'
	touch $@

setup: $(BIN)/coster-sumo

# full COSTER with the shipped weights on the package's own intersection network; the target replays
# its nominal path so every contact is at t_col
demo: setup
	$(BIN)/coster-sumo demo -o $(OUT) --overwrite

lint: setup
	$(BIN)/ruff check .
	$(BIN)/mypy coster_sumo converters

test: lint
	$(BIN)/python -m pytest -q -m "not slow"

test-slow: setup
	$(BIN)/python -m pytest -q -m "slow" || [ $$? -eq 5 ]  # 5 = no slow tests collected

# the third-party OpenDRIVE readers, each in its own environment, at the versions pyproject.toml's
# extras xodr-asam and xodr-readers pin (tests/exports/test_xodr_readers.py skips without them)
xodr-readers: setup
	for extra in xodr-asam xodr-readers; do \
	  test -x .venv-$$extra/bin/python || $(PYTHON) -m venv .venv-$$extra; \
	  .venv-$$extra/bin/python -m pip install -q $$($(BIN)/python -c "import tomllib; \
	    print(' '.join(tomllib.load(open('pyproject.toml', 'rb'))['project']['optional-dependencies']['$$extra']))"); \
	done

clean:
	rm -rf $(VENV) .venv-xodr-asam .venv-xodr-readers out .pytest_cache .mypy_cache .ruff_cache
