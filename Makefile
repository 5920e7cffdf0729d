# Two commands for a fresh machine: `make demo` and `make test`.
# Both create .venv, install the project with its test extras, then run.
PYTHON ?= python3
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed
# the studies (lab/: benches, report, fuzz, the serial board) run from the checkout, beside the
# installed package; they are not in the wheel
LAB := $(BIN)/python -m lab

.PHONY: demo test install clean wheel wheelhouse-check lint-imports report speed-accuracy stability timing faults fuzz busy grips soak firmware firmware-host firmware-sim firmware-deps

$(STAMP): pyproject.toml setup.py
	$(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip
	$(BIN)/python -m pip install --quiet -e '.[test]'
	touch $(STAMP)

install: $(STAMP)

demo: $(STAMP)
	$(BIN)/fluidsense demo

# The serial driver's tests run the firmware's host board (gcc only) and, where Debian's
# AVR packages are installed, the AVR image in simavr. CI (CI=true, a fresh machine)
# installs those packages first (firmware-deps; firmware/README.md says why); elsewhere
# `make firmware-deps` does, and without them the AVR tests are skipped, said in one line.
test: $(STAMP) firmware-host
	@if [ "$$CI" = true ]; then $(MAKE) -s firmware-deps || echo "make test: installing $(AVR_DEBS) failed"; fi
	@if $(AVR_READY); then $(MAKE) -s firmware-sim; else echo "make test: $(AVR_DEBS) not installed (make \
	firmware-deps): the AVR image's tests are skipped, the host board's run"; fi
	$(BIN)/python -m pytest -n 2 --dist loadfile --no-loadscope-reorder

# The serial streamer's firmware (firmware/README.md): the AVR image (size reported; needs
# gcc-avr and avr-libc) and the host board that runs behind a pty in the tests.
firmware:
	$(MAKE) -C firmware all

firmware-host:
	$(MAKE) -C firmware host

# The AVR image and the simulated board that runs it in simavr (python -m lab simserial --board avr).
firmware-sim:
	$(MAKE) -C firmware sim

# Debian's packages for the AVR image and its simulator, installed with apt-get when
# missing (as root, as on CI and the developers' machines); ~15-30 s.
AVR_DEBS := gcc-avr avr-libc simavr libsimavr-dev
AVR_READY := command -v avr-gcc >/dev/null 2>&1 && test -f /usr/include/simavr/sim_avr.h
firmware-deps:
	@if $(AVR_READY); then :; \
	elif [ "$$(id -u)" = 0 ] && command -v apt-get >/dev/null; then \
		echo "make firmware-deps: apt-get install $(AVR_DEBS)"; \
		apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq $(AVR_DEBS) >/dev/null; \
	else echo "make firmware-deps: as root: apt-get install $(AVR_DEBS)"; exit 1; fi

# Regenerates docs/reproduction (the paper's numbers beside ours; a few minutes).
report: $(STAMP)
	$(LAB) report --out docs/reproduction

# Regenerates docs/speed-accuracy (accuracy against decision time, every method; ~2 minutes).
speed-accuracy: $(STAMP)
	$(LAB) bench speed-accuracy --out docs/speed-accuracy

# Regenerates docs/stability (perturbations, failures, mitigations; ~4 minutes).
stability: $(STAMP)
	$(LAB) bench stability --out docs/stability

# 1 kHz timing figures of docs/performance.md (TIMING_S seconds per run; 600 in the doc; the
# AVR image's run needs `make firmware-deps`).
TIMING_S ?= 600
timing: $(STAMP)
	mkdir -p docs/performance
	$(LAB) bench sim --json > docs/performance/sim.json
	$(LAB) bench timing --source sim --seconds $(TIMING_S) --json > docs/performance/timing-sim.json
	$(LAB) bench timing --source modbus --seconds $(TIMING_S) --json > docs/performance/timing-modbus.json
	$(LAB) bench timing --source serial --seconds $(TIMING_S) --json > docs/performance/timing-serial.json
	$(LAB) bench timing --source serial --board avr --seconds $(TIMING_S) --json > docs/performance/timing-serial-avr.json
	$(LAB) bench sampler --seconds 60 --json > docs/performance/sampler.json

# Fault-injection figures of docs/safety.md: in-process faults, then what only the box can
# vent (killed daemon, pulled cable, SIGTERM) against fluidsense simcell (~10 minutes).
faults: $(STAMP)
	mkdir -p docs/safety
	$(LAB) bench faults --box-runs 5 --json > docs/safety/faults.json

# Hostile input figures of docs/safety.md: command messages and config files (~5 minutes).
fuzz: $(STAMP)
	mkdir -p docs/safety
	$(LAB) bench fuzz --messages 10000 --files 20000 --json > docs/safety/fuzz.json

# The busy robot PC of docs/performance.md: the README's sorting task through ur and modbus
# beside two busy processes, 10 runs each, then an idle daemon for 10 minutes (~1 hour).
busy: $(STAMP)
	mkdir -p docs/performance
	$(LAB) bench tasks --runs 10 --load 2 --idle-s 600 --json > docs/performance/busy.json

# Empty grips on a busy robot PC, with and without the rise alignment (docs/physics.md
# "Timing the valve"): 20 per driver and setting beside two busy processes (~12 minutes).
grips: $(STAMP)
	mkdir -p docs/performance
	$(LAB) bench tasks --runs 0 --load 2 --empty-grips 20 --json > docs/performance/empty-grips.json

# Soak figures of docs/soak.md: 8 hours of sample time in virtual time (~10 minutes).
soak: $(STAMP)
	mkdir -p docs/soak
	$(LAB) bench soak --virtual-hours 8 --json > docs/soak/soak-8h.json

# The project as a wheel (dist/), configs, profiles and tasks inside it as package data.
wheel: $(STAMP)
	$(BIN)/python -m pip wheel --no-deps --quiet --wheel-dir dist .

# The Docker image's two pip steps on this host (no Docker engine here): every runtime
# wheel built into a wheelhouse, a fresh venv installs from it alone (no index, no test
# extras), then `fluidsense demo` runs from a directory outside the checkout (~3 minutes).
WHEELHOUSE_TMP := $(shell mktemp -d -u /tmp/fluidsense-wheelhouse.XXXXXX)
wheelhouse-check:
	$(PYTHON) -m venv $(WHEELHOUSE_TMP)/venv
	$(WHEELHOUSE_TMP)/venv/bin/python -m pip wheel --quiet --wheel-dir $(WHEELHOUSE_TMP)/wheels .
	$(WHEELHOUSE_TMP)/venv/bin/python -m pip install --quiet --no-index --find-links $(WHEELHOUSE_TMP)/wheels fluidsense
	mkdir -p $(WHEELHOUSE_TMP)/elsewhere
	cd $(WHEELHOUSE_TMP)/elsewhere && $(WHEELHOUSE_TMP)/venv/bin/fluidsense demo
	rm -rf $(WHEELHOUSE_TMP)

lint-imports: $(STAMP)
	$(BIN)/lint-imports

clean:
	rm -rf $(VENV) build dist *.egg-info .pytest_cache firmware/build
