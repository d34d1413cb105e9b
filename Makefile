# One-command entry points. `make demo` and `make test` work on a fresh machine with Python 3.11.
PY ?= python3.11
VENV := .venv
BIN := $(VENV)/bin

.PHONY: setup demo test lint clean

$(BIN)/jsrte: pyproject.toml
	@bash scripts/setup.sh "$(PY)"
	@touch $(BIN)/jsrte

setup: $(BIN)/jsrte

demo: setup
	$(BIN)/jsrte demo

test: setup
	@bash scripts/setup-test-extras.sh
	$(BIN)/ruff check src tests benchmarks
	$(BIN)/python -m pytest -q -n 2 --dist loadfile

lint: setup
	$(BIN)/ruff check src tests benchmarks

clean:
	rm -rf $(VENV) build *.egg-info src/*.egg-info .pytest_cache
