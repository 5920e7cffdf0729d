# Two commands for a fresh machine: `make demo` and `make test`; two more for the suite's other
# uses: `make check` (the unit tier, on every change) and `make accept` (the acceptance tier).
# Each creates .venv, installs the project with its test extras, then runs.
PYTHON ?= python3
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed
# the studies (lab/: benches, report, fuzz, the serial board) run from the checkout, beside the
# installed package; they are not in the wheel
LAB := $(BIN)/python -m lab

.PHONY: demo check test accept suite-cpu install clean wheel image-deps image-check image-base image-clean lint-imports report speed-accuracy stability timing faults fuzz busy grips soak firmware firmware-host firmware-sim firmware-deps

$(STAMP): pyproject.toml setup.py
	$(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip
	$(BIN)/python -m pip install --quiet -e '.[test]'
	touch $(STAMP)

install: $(STAMP)

demo: $(STAMP)
	$(BIN)/fluidsense demo

# The suite has three tiers, by folder (tests/README.md):
#   tests/unit/    in this process only (an autouse guard fails a test that starts a process or
#                  opens a socket other than inproc://); 60 s per test
#   tests/system/  real peers: daemons, `fluidsense simcell` boxes, the firmware's boards on
#                  ptys, Modbus servers, RTDE clients; 300 s per test
#   tests/accept/  the documents walked as written (README.md, docs/bringup.md,
#                  examples/README.md, docs/deployment.md's install), the production image,
#                  the long runs of the AVR image; each test names its own timeout
# `make check`: the unit tier, what a developer runs on every change (the goal: under 90 s on a
# quiet 2-core machine; about 115 s of CPU in all, measured on a shared one).
check: $(STAMP)
	$(BIN)/python -m pytest tests/unit -n 2

# `make test`: the unit and system tiers, the README's test command. The system tier's serial
# tests run the firmware's host board (gcc only) and, where Debian's AVR packages are
# installed, the AVR image in simavr. CI (CI=true, a fresh machine) installs those packages
# first (firmware-deps; firmware/README.md says why); elsewhere `make firmware-deps` does,
# and without them the AVR tests are skipped, said in one line. --dist loadfile hands whole
# files to the workers, longest first (tests/conftest.py LONGEST_FIRST). Three workers on two
# cores: the real-time tests wait on their boxes and daemons, and a third worker fills those
# waits (on the quiet 2-core machine 12 min 38 s, the cores 91 % busy, against 15 min and
# 73 % with two: docs/architecture.md). The acceptance tier keeps two: its walks are
# real-time runs of minutes beside the image build. A unit test past its minute ends its
# worker (tests/conftest.py TIER_TIMEOUT_METHOD); xdist then gives that file to a new
# worker, which meets the same test: two such restarts end the run.
XDIST_OPTS := --dist loadfile --no-loadscope-reorder --max-worker-restart 2 --durations=30 --durations-min=5
PYTEST_XDIST := -n 2 $(XDIST_OPTS)
PYTEST_XDIST_TEST := -n 3 $(XDIST_OPTS)
test: $(STAMP) firmware-host
	@if [ "$$CI" = true ]; then $(MAKE) -s firmware-deps || echo "make test: installing $(AVR_DEBS) failed"; fi
	@if $(AVR_READY); then $(MAKE) -s firmware-sim; else echo "make test: $(AVR_DEBS) not installed (make \
	firmware-deps): the AVR image's tests are skipped, the host board's run"; fi
	$(BIN)/python -m pytest tests/unit tests/system $(PYTEST_XDIST_TEST)

# `make accept`: the acceptance tier. As root it installs what it needs with apt-get: the AVR
# toolchain and simavr (firmware-deps) and podman, runc and debootstrap (image-check); not
# root and without them, those tests are skipped, each saying why. `make image-check` runs
# beside the tier, in the background: it mostly waits on the network and the engine, and
# tests/accept/test_ship.py waits for its result (FLUIDSENSE_IMAGE_CHECK_LOG) instead of
# holding a worker for its minutes.
accept: $(STAMP) firmware-host
	@$(MAKE) -s firmware-deps || echo "make accept: installing $(AVR_DEBS) failed"
	@if $(AVR_READY); then $(MAKE) -s firmware-sim; else echo "make accept: $(AVR_DEBS) not installed (make \
	firmware-deps, as root): the AVR image's runs are skipped"; fi
	@$(MAKE) -s image-deps || echo "make accept: installing $(IMAGE_TOOLS) failed"
	@log=; if $(IMAGE_READY); then \
		log=$$(mktemp /tmp/fluidsense-image-check.XXXXXX); export FLUIDSENSE_IMAGE_CHECK_LOG=$$log; \
		{ $(IMAGE_CHECK) > $$log 2>&1; echo "exit $$?" >> $$log; } & \
	else echo "make accept: $(IMAGE_MISSING)"; fi; \
	echo "$(BIN)/python -m pytest tests/accept $(PYTEST_XDIST)"; \
	$(BIN)/python -m pytest tests/accept $(PYTEST_XDIST); rc=$$?; \
	wait; if [ -n "$$log" ]; then grep -h "^image-check: image size" $$log; \
		grep -qx "exit 0" $$log && rm -f $$log || echo "make accept: make image-check failed: $$log"; fi; \
	exit $$rc

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

# Hostile input figures of docs/safety.md: command messages, config files and a serial device's
# frames (~8 minutes).
fuzz: $(STAMP)
	mkdir -p docs/safety
	$(LAB) bench fuzz --messages 10000 --files 20000 --serial 1000 --json > docs/safety/fuzz.json

# The busy robot PC of docs/performance.md: the README's sorting task through ur and modbus
# beside two busy processes, 10 runs each, then an idle daemon for 10 minutes (~1 hour).
busy: $(STAMP)
	mkdir -p docs/performance
	$(LAB) bench tasks --runs 10 --load 2 --idle-s 600 --json > docs/performance/busy.json

# Empty grips and grips on cylinders through ur and modbus (the shipped sorting cells), quiet
# and beside two busy processes (docs/performance.md "Empty grips and objects"; ~1.5 hours)
grips: $(STAMP)
	mkdir -p docs/performance
	$(LAB) bench grips --loads 0,2 --empty 100 --sizes 40,60,100 --objects 5 --json > docs/performance/grips.json

# Where make test's CPU goes (tests/README.md): its pytest run, with each test's CPU and each
# process the tests start reported, per test file and per kind of process. The firmware
# images it tests are make test's to build; without them their tests skip.
suite-cpu: $(STAMP) firmware-host
	$(LAB) bench suite-cpu -- tests/unit tests/system $(PYTEST_XDIST_TEST)

# Soak figures of docs/soak.md: 8 hours of sample time in virtual time (~10 minutes).
soak: $(STAMP)
	mkdir -p docs/soak
	$(LAB) bench soak --virtual-hours 8 --json > docs/soak/soak-8h.json

# The project as a wheel (dist/), configs, profiles and tasks inside it as package data.
wheel: $(STAMP)
	$(BIN)/python -m pip wheel --no-deps --quiet --wheel-dir dist .

# ------------------------------------------------------------------- the production image
# `make image-check` (docs/deployment.md "Container"): builds a base image from Debian with
# debootstrap (python3 from apt; no image registry needed), the Dockerfile on it with podman,
# then runs the image and checks what a deployment relies on (tests/support/image_check.py:
# the non-root daemon on the simulated cell, `fluidsense cmd status` from the host through
# the published command port, the engine's healthcheck, the config and runs volumes, SIGTERM,
# pip list) and prints the image's size and start-up time. As root it installs podman, runc
# and debootstrap with apt-get when they are missing (image-deps); `make accept` runs it
# beside the acceptance tier. The base is made once and kept (`make image-clean` removes it
# and the images).
#
# The engine's flags, in one place, for the machines this project is built and tested on:
#   --runtime runc   crun refuses their hybrid (v1 and v2 mixed) cgroup hierarchy ("cgroups in
#                    hybrid mode not supported"); runc runs there
#   --ulimit ...     the engine's default open-files and processes limits are above the hard
#                    limits a process gets there, and runc cannot raise them ("error setting
#                    rlimits", each of the two on its own); 1024 is plenty for the daemon
#   --network host   builds only: a build reaches the package registries as the host does
#   --format docker  builds only: OCI images have no HEALTHCHECK; podman keeps it in this format
#   --layers=false   builds only: nothing of a build is left behind but its image (no
#                    intermediate images piling up from run to run)
#   PIP_CERT         when set in the environment (the CA bundle of a TLS-inspecting proxy), it
#                    is mounted into the build and named to pip
ENGINE := podman
ENGINE_FLAGS := --runtime runc --ulimit nofile=1024:1024 --ulimit nproc=1024:1024
ENGINE_BUILD_FLAGS := $(ENGINE_FLAGS) --network host --format docker --layers=false \
	$(if $(PIP_CERT),--volume $(PIP_CERT):/run/pip-ca.crt:ro --build-arg PIP_CERT=/run/pip-ca.crt)
IMAGE_BASE := localhost/fluidsense-base:bookworm
IMAGE_TOOLS := podman runc debootstrap
IMAGE_READY = [ "$$(id -u)" = 0 ] && command -v podman >/dev/null && command -v runc >/dev/null \
	&& command -v debootstrap >/dev/null
# through a variable: a recipe line naming $(MAKE) itself would run even under `make -n`
IMAGE_CHECK = $(MAKE) --no-print-directory image-check
IMAGE_MISSING = podman, runc or debootstrap not installed, or not root: the production image is not built \
	or run (make image-check, as root, installs them and does both)

# podman, runc and debootstrap, installed with apt-get where missing (as root)
image-deps:
	@missing=$$(for t in $(IMAGE_TOOLS); do command -v $$t >/dev/null || echo $$t; done); \
	if [ -n "$$missing" ]; then \
		[ "$$(id -u)" = 0 ] || { echo "make image-deps: needs $$missing (apt-get install $(IMAGE_TOOLS), as root)"; exit 1; }; \
		echo "make image-deps: installing $$missing"; \
		apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq $(IMAGE_TOOLS) >/dev/null; \
	fi

image-check: $(STAMP) image-deps
	@$(ENGINE) image exists $(IMAGE_BASE) || $(MAKE) --no-print-directory image-base
	@tag=localhost/fluidsense:check-$$$$; log=$$(mktemp /tmp/fluidsense-image-build.XXXXXX); \
	echo "make image-check: building $$tag on $(IMAGE_BASE) (log: $$log)"; \
	start=$$(date +%s); \
	$(ENGINE) build $(ENGINE_BUILD_FLAGS) --build-arg BASE=$(IMAGE_BASE) --tag $$tag . > $$log 2>&1 \
		|| { tail -n 30 $$log; echo "make image-check: the build failed (all of it: $$log)"; exit 1; }; \
	echo "make image-check: built in $$(( $$(date +%s) - start )) s"; rm -f $$log; \
	$(BIN)/python tests/support/image_check.py --engine $(ENGINE) --run-flags "$(ENGINE_FLAGS)" \
		--base $(IMAGE_BASE) $$tag; rc=$$?; \
	$(ENGINE) rmi --force $$tag >/dev/null; exit $$rc

# Debian bookworm, minimal, with python3 from apt, as a local base image (~1-2 minutes)
image-base:
	@root=$$(mktemp -d /tmp/fluidsense-base.XXXXXX); start=$$(date +%s); \
	echo "make image-base: debootstrap bookworm into $$root"; \
	debootstrap --variant=minbase --include=python3 bookworm $$root > $$root.log 2>&1 \
		|| { tail -n 20 $$root.log; rm -rf $$root $$root.log; exit 1; }; \
	rm -rf $$root/var/cache/apt/archives/*.deb $$root/var/lib/apt/lists/*; \
	tar -C $$root -c . | $(ENGINE) import --quiet - $(IMAGE_BASE) >/dev/null; rc=$$?; \
	rm -rf $$root $$root.log; [ $$rc != 0 ] || echo "make image-base: made in $$(( $$(date +%s) - start )) s"; exit $$rc

image-clean:
	-$(ENGINE) rmi --force $(IMAGE_BASE) $$($(ENGINE) images --quiet --filter reference='localhost/fluidsense:check-*')

lint-imports: $(STAMP)
	$(BIN)/lint-imports

clean:
	rm -rf $(VENV) build dist *.egg-info .pytest_cache firmware/build
