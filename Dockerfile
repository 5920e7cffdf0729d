# fluidsense daemon on the simulated cell (real time). Installs exactly as the Makefile
# does (`make install`: a venv in .venv with the project and its test extras; .dockerignore
# keeps a host .venv out, else its stamp would turn the install into a no-op), then runs
# `fluidsense run`. Build: docker build -t fluidsense .   Run: docker run -p 5560:5560 fluidsense
FROM python:3.11-slim
WORKDIR /opt/fluidsense
RUN apt-get update && apt-get install -y --no-install-recommends make && rm -rf /var/lib/apt/lists/*
COPY . .
RUN make install
# Events on every interface of the container (config/cell-sim-container.yaml); the command
# socket stays on loopback inside it: docker exec <ctr> .venv/bin/fluidsense cmd status
EXPOSE 5560
# SIGTERM (docker stop) aborts a running cycle, vents, closes the sockets and exits 0.
STOPSIGNAL SIGTERM
CMD [".venv/bin/fluidsense", "run", "--config", "config/cell-sim-container.yaml"]
