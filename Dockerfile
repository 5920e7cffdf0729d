# fluidsense daemon, production image (docs/deployment.md "Docker").
# Stage 1 builds the project's wheel and the wheels of its runtime dependencies; stage 2
# installs only those (no test extras, no compiler, no sources) and runs as a user of its
# own. `make wheelhouse-check` runs the same two pip steps on the host, where no Docker
# engine is available. Tests run from the Makefile (`make test`), never from this image.
#   docker build -t fluidsense .
#   docker run --rm -p 5560:5560 -v fluidsense-runs:/var/lib/fluidsense/runs fluidsense
FROM python:3.11-slim AS build
WORKDIR /src
COPY . .
RUN python -m pip wheel --no-cache-dir --wheel-dir /wheels .

FROM python:3.11-slim
RUN useradd --system --uid 10001 --user-group --home-dir /var/lib/fluidsense --create-home \
        --shell /usr/sbin/nologin fluidsense \
    && mkdir -p /etc/fluidsense /var/lib/fluidsense/runs \
    && chown fluidsense:fluidsense /var/lib/fluidsense/runs
COPY --from=build /wheels /tmp/wheels
RUN python -m pip install --no-cache-dir --no-index --find-links /tmp/wheels fluidsense \
    && rm -rf /tmp/wheels
# The default cell: the simulated cell in real time, events on every interface of the
# container, commands on loopback inside it. Mount your own /etc/fluidsense (cell.yaml,
# profiles/, tasks/) for a real cell; recordings go to the runs volume.
COPY config/cell-sim-container.yaml /etc/fluidsense/cell.yaml
COPY config/profiles /etc/fluidsense/profiles
COPY config/tasks /etc/fluidsense/tasks
VOLUME ["/etc/fluidsense", "/var/lib/fluidsense/runs"]
WORKDIR /var/lib/fluidsense
USER fluidsense
EXPOSE 5560
# healthy = the daemon answers on its command socket (exit 0 only on an ok reply)
HEALTHCHECK --interval=30s --timeout=10s --start-period=60s --retries=3 \
    CMD ["fluidsense", "cmd", "status", "--config", "/etc/fluidsense/cell.yaml", "--timeout", "5"]
# SIGTERM (docker stop) aborts a running cycle, vents, closes the sockets and exits 0.
STOPSIGNAL SIGTERM
CMD ["fluidsense", "run", "--config", "/etc/fluidsense/cell.yaml", "--tasks-dir", "/etc/fluidsense/tasks"]
