# Two commands for a fresh machine with only Python and pip: `make demo` and `make test`.
PYTHON ?= python3
VENV ?= .venv
BIN := $(VENV)/bin
PIP_FLAGS ?= -q --disable-pip-version-check

.PHONY: demo test lint format bench study clean

$(BIN)/python:
	$(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install $(PIP_FLAGS) --upgrade pip

$(VENV)/.installed: $(BIN)/python pyproject.toml
	$(BIN)/python -m pip install $(PIP_FLAGS) -e .
	touch $@

$(VENV)/.installed-test: $(BIN)/python pyproject.toml
	$(BIN)/python -m pip install $(PIP_FLAGS) -e ".[test]"
	touch $@ $(VENV)/.installed

demo: $(VENV)/.installed
	$(BIN)/pliant demo --out out

test: $(VENV)/.installed-test
	$(BIN)/ruff check pliant tests benchmarks examples
	$(BIN)/ruff format --check pliant tests benchmarks examples
	$(BIN)/python -m pytest -q

lint: $(VENV)/.installed-test
	$(BIN)/ruff check --fix pliant tests benchmarks examples
	$(BIN)/ruff format pliant tests benchmarks examples

bench: $(VENV)/.installed
	$(BIN)/pliant bench

study: $(VENV)/.installed
	$(BIN)/pliant study integrators --out docs/figures

clean:
	rm -rf $(VENV) out .pytest_cache .ruff_cache *.egg-info
