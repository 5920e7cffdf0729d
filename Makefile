# Two commands for a fresh machine: `make demo` and `make test`.
# Both create .venv, install the project with its test extras, then run.
PYTHON ?= python3
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed

.PHONY: demo test install clean lint-imports report

$(STAMP): pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip
	$(BIN)/python -m pip install --quiet -e '.[test]'
	touch $(STAMP)

install: $(STAMP)

demo: $(STAMP)
	$(BIN)/fluidsense demo

test: $(STAMP)
	$(BIN)/python -m pytest

# Regenerates docs/reproduction (the paper's numbers beside ours; a few minutes).
report: $(STAMP)
	$(BIN)/fluidsense report --out docs/reproduction

lint-imports: $(STAMP)
	$(BIN)/lint-imports

clean:
	rm -rf $(VENV) build *.egg-info .pytest_cache
