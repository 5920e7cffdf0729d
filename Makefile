# Two commands for a fresh machine: `make demo` and `make test`.
# Both create .venv, install the project with its test extras, then run.
PYTHON ?= python3
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed

.PHONY: demo test install clean lint-imports report speed-accuracy stability

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

# Regenerates docs/speed-accuracy (accuracy against decision time, every method; ~2 minutes).
speed-accuracy: $(STAMP)
	$(BIN)/fluidsense bench speed-accuracy --out docs/speed-accuracy

# Regenerates docs/stability (perturbations, failures, mitigations; ~4 minutes).
stability: $(STAMP)
	$(BIN)/fluidsense bench stability --out docs/stability

lint-imports: $(STAMP)
	$(BIN)/lint-imports

clean:
	rm -rf $(VENV) build *.egg-info .pytest_cache
