# Two commands for a fresh machine: `make demo` and `make test`.
# Both create .venv, install the project with its test extras, then run.
PYTHON ?= python3
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed

.PHONY: demo test install clean lint-imports report speed-accuracy stability timing faults soak

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

# 1 kHz timing figures of docs/performance.md (TIMING_S seconds per run; 600 in the doc).
TIMING_S ?= 600
timing: $(STAMP)
	mkdir -p docs/performance
	$(BIN)/fluidsense bench sim --json > docs/performance/sim.json
	$(BIN)/fluidsense bench timing --source sim --seconds $(TIMING_S) --json > docs/performance/timing-sim.json
	$(BIN)/fluidsense bench timing --source modbus --seconds $(TIMING_S) --json > docs/performance/timing-modbus.json
	$(BIN)/fluidsense bench sampler --seconds 60 --json > docs/performance/sampler.json

# Fault-injection figures of docs/safety.md (~2 minutes).
faults: $(STAMP)
	mkdir -p docs/safety
	$(BIN)/fluidsense bench faults --json > docs/safety/faults.json

# Soak figures of docs/soak.md: 8 hours of sample time in virtual time (~10 minutes).
soak: $(STAMP)
	mkdir -p docs/soak
	$(BIN)/fluidsense bench soak --virtual-hours 8 --json > docs/soak/soak-8h.json

lint-imports: $(STAMP)
	$(BIN)/lint-imports

clean:
	rm -rf $(VENV) build *.egg-info .pytest_cache
