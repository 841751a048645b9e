# Two commands for a fresh machine with only Python and pip: `make demo` and `make test`.
PYTHON ?= python3
VENV ?= .venv
BIN := $(VENV)/bin
PIP_FLAGS ?= -q --disable-pip-version-check

.PHONY: demo test docs lint format bench study clean

$(BIN)/python:
	$(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install $(PIP_FLAGS) --upgrade pip

$(VENV)/.installed: $(BIN)/python pyproject.toml
	$(BIN)/python -m pip install $(PIP_FLAGS) -e .
	touch $@

$(VENV)/.installed-test: $(BIN)/python pyproject.toml
	$(BIN)/python -m pip install $(PIP_FLAGS) -e ".[test]"
	touch $@ $(VENV)/.installed

$(VENV)/.installed-docs: $(BIN)/python pyproject.toml
	$(BIN)/python -m pip install $(PIP_FLAGS) -e ".[docs]"
	touch $@ $(VENV)/.installed

demo: $(VENV)/.installed
	$(BIN)/pliant demo --out out

# The docs are part of the suite: tests/test_docs.py builds the site with `mkdocs build --strict` and runs
# every tutorial's code, so `make test` stays CI's single entry. One pytest-xdist worker per core: the suite
# (about 1460 tests) took 9.9 minutes on two shared cores from a fresh clone with an empty Warp kernel cache
# (11.4 minutes with the venv's set-up, ruff and the type check; 2026-11-26, `CI=true bash .ci/run`).
test: $(VENV)/.installed-test
	$(BIN)/ruff check pliant tests benchmarks examples
	$(BIN)/ruff format --check pliant tests benchmarks examples
	$(BIN)/python tests/typecheck.py
	$(BIN)/python -m pytest -q -n auto

# The documentation site (mkdocs-material + mkdocstrings) into site/; warnings are errors.
docs: $(VENV)/.installed-docs
	NO_MKDOCS_2_WARNING=1 $(BIN)/python -m mkdocs build --strict --site-dir site

lint: $(VENV)/.installed-test
	$(BIN)/ruff check --fix pliant tests benchmarks examples
	$(BIN)/ruff format pliant tests benchmarks examples

bench: $(VENV)/.installed
	$(BIN)/pliant bench

study: $(VENV)/.installed
	$(BIN)/pliant study integrators --out docs/figures

clean:
	rm -rf $(VENV) out site .pytest_cache .ruff_cache .mypy_cache *.egg-info
