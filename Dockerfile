# fluidsense daemon on the simulated cell. Mirrors the Makefile: a venv in .venv with the
# project and its test extras, then `fluidsense run`. Build: docker build -t fluidsense .
FROM python:3.11-slim
WORKDIR /opt/fluidsense
RUN apt-get update && apt-get install -y --no-install-recommends make && rm -rf /var/lib/apt/lists/*
COPY . .
RUN make install
# The default config binds loopback only; inside a container publish on all interfaces
# explicitly, e.g. with a config whose publisher.pub is tcp://0.0.0.0:5560.
EXPOSE 5560 5561
STOPSIGNAL SIGTERM
CMD [".venv/bin/fluidsense", "run", "--config", "config/cell-sim.yaml"]
