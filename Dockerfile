# fluidsense daemon, production image (docs/deployment.md "Container").
#   docker build -t fluidsense .                 # or: podman build --format docker -t fluidsense .
#   docker run --rm -p 5560:5560 -v fluidsense-runs:/var/lib/fluidsense/runs fluidsense
# The base is a build argument: the official slim Python image by default; `make image-check`
# builds it on a Debian root made by debootstrap with python3 from apt, and runs it. Whatever
# the image needs beyond a Python 3.11 or newer on Debian is installed here. Stage "build"
# builds the project's wheel and the wheels of its runtime dependencies; the last stage
# installs only those (no test extras, no compiler, no sources) into the venv the systemd
# unit names too (/opt/fluidsense/venv), and runs as a user of its own. Tests run from the
# Makefile (`make test`), never from this image.
ARG BASE=python:3.11-slim

FROM ${BASE} AS python
# A Debian python3 from apt comes without venv (ensurepip) and, in a minimal root, without
# the CA bundle pip needs: take them from the base's own packages when they are missing.
RUN missing=""; \
    python3 -c "import ensurepip" 2>/dev/null || missing="$missing python3-venv"; \
    [ -e /etc/ssl/certs/ca-certificates.crt ] || missing="$missing ca-certificates"; \
    command -v useradd >/dev/null || missing="$missing passwd"; \
    if [ -n "$missing" ]; then \
        apt-get update && apt-get install -y --no-install-recommends $missing \
        && rm -rf /var/lib/apt/lists/*; \
    fi
ENV PATH=/opt/fluidsense/venv/bin:$PATH

FROM python AS build
# PIP_CERT: a CA bundle for a build behind a TLS-inspecting proxy (mounted by the engine;
# `make image-check` passes the host's when PIP_CERT is set there). Unset, pip uses its own.
ARG PIP_CERT
WORKDIR /src
COPY . .
# the wheel as `make wheel` builds it, then the install of docs/deployment.md: that wheel
# into the venv, its runtime dependencies from the index, no extras
RUN python3 -m venv /opt/fluidsense/venv \
    && pip wheel --no-cache-dir --no-deps --wheel-dir /dist . \
    && pip install --no-cache-dir /dist/fluidsense-*.whl

FROM python
# the venv moves whole (same path, same interpreter): no wheel, source or build tool is left
# in a layer of this stage
COPY --from=build /opt/fluidsense/venv /opt/fluidsense/venv
# The default cell: the simulated cell in real time, events on every interface of the
# container, commands on loopback inside it, with the shipped profiles and tasks, all taken
# from the installed wheel as the systemd install does. Mount your own /etc/fluidsense
# (cell.yaml, profiles/, tasks/) for a real cell; recordings go to the runs volume.
RUN useradd --system --uid 10001 --user-group --home-dir /var/lib/fluidsense --create-home \
        --shell /usr/sbin/nologin fluidsense \
    && install -d -o fluidsense -g fluidsense -m 0750 /var/lib/fluidsense/runs \
    && shipped="$(python -c 'from fluidsense.config import SHIPPED; print(SHIPPED)')" \
    && install -d -m 0755 /etc/fluidsense \
    && cp "$shipped/cell-sim-container.yaml" /etc/fluidsense/cell.yaml \
    && cp -r "$shipped/profiles" "$shipped/tasks" /etc/fluidsense/
VOLUME ["/etc/fluidsense", "/var/lib/fluidsense/runs"]
WORKDIR /var/lib/fluidsense
USER fluidsense
EXPOSE 5560
# healthy = heartbeats arrive: the sample loop publishes one every heartbeat_s (1 s) while it
# makes progress, whichever driver and whether or not the command socket needs CURVE keys
# (the container's counterpart of the unit's watchdog; exit 1 when none came within 10 s)
HEALTHCHECK --interval=30s --timeout=30s --start-period=60s --retries=3 \
    CMD ["fluidsense", "monitor", "--config", "/etc/fluidsense/cell.yaml", "--topic", "heartbeat", "--count", "1", "--timeout", "10"]
# SIGTERM (docker stop) aborts a running cycle, vents, flushes and closes the recording and
# the sockets, and exits 0.
STOPSIGNAL SIGTERM
CMD ["fluidsense", "run", "--config", "/etc/fluidsense/cell.yaml", "--tasks-dir", "/etc/fluidsense/tasks"]
