"""Shipping: the production Dockerfile (read here, and built and run by `make image-check`
where podman is installed), the wheel (built here and run from outside the checkout with
its configs as package data), and docs/deployment.md's install from that wheel, run in a
scratch root, whose unit systemd-analyze verifies and which agrees with the image.

(Its acceptance runs: tests/accept/test_ship.py.)
"""

from __future__ import annotations

import json
import re
from fluidsense.controller.config import load_cell_config
from support.harness import REPO
from support.shipping import dockerfile, stages


def test_the_image_takes_its_base_as_an_argument_and_ships_the_venv_alone_as_a_user_of_its_own():
    """The Dockerfile read (``make image-check`` builds and runs it: the test below)."""
    steps = dockerfile()
    text = (REPO / "Dockerfile").read_text()
    # the base: a build argument whose default is the official slim Python that meets requires-python
    default = re.search(r"^ARG BASE=python:(\d+)\.(\d+)-slim$", text, re.M)
    required = re.search(r'requires-python = ">=(\d+)\.(\d+)"', (REPO / "pyproject.toml").read_text())
    assert default and required and tuple(map(int, default.groups())) >= tuple(map(int, required.groups()))
    by = stages(steps)
    assert list(by) == ["python", "build", "final"], list(by)
    assert by["python"][0][1] == "${BASE} AS python" and by["build"][0][1] == "python AS build"
    assert by["final"][0][1] == "python"
    # the build stage makes the wheel and installs it into the venv, no extras, no editable install
    build_runs = " ".join(a for k, a in by["build"] if k == "RUN")
    assert "pip wheel" in build_runs and "--no-deps" in build_runs
    assert re.search(r"pip install (--\S+ )*/dist/fluidsense-\*\.whl", build_runs), build_runs
    assert "[" not in build_runs and " -e " not in build_runs and "make" not in build_runs.split()
    # the last stage takes the venv alone from it: no sources, no wheels, no compiler
    final = by["final"]
    copies = [a for k, a in final if k == "COPY"]
    assert copies == ["--from=build /opt/fluidsense/venv /opt/fluidsense/venv"], copies
    assert "pip" not in " ".join(a for k, a in final if k == "RUN").split()
    # a user of its own, set after every RUN (root only while installing)
    users = [i for i, (k, _) in enumerate(final) if k == "USER"]
    assert users and final[users[-1]][1] not in ("root", "0", "0:0")
    assert max(i for i, (k, _) in enumerate(final) if k == "RUN") < users[-1]
    # healthy = heartbeats arrive on the event socket (no command keys needed)
    health = dict(final)["HEALTHCHECK"]
    cmd = json.loads(health.split("CMD", 1)[1])
    assert cmd[:2] == ["fluidsense", "monitor"] and cmd[cmd.index("--topic") + 1] == "heartbeat"
    # config and recordings are volumes; the default cell exists in the wheel, validates, and
    # records into the runs volume
    volumes = json.loads(dict(final)["VOLUME"])
    run = json.loads(dict(final)["CMD"])
    assert run[:3] == ["fluidsense", "run", "--config"] and run[3] == volumes[0] + "/cell.yaml"
    assert re.search(r'cp "\$shipped/cell-sim-container.yaml" ' + re.escape(run[3]), text)
    cfg = load_cell_config(REPO / "config" / "cell-sim-container.yaml")
    assert cfg.driver.kind == "sim" and cfg.recording.enabled and not cfg.recording.dir.startswith("/")
    assert dict(final)["WORKDIR"] + "/" + cfg.recording.dir in volumes
    assert cfg.publisher.cmd.startswith("tcp://127.0.0.1:") and cfg.publisher.pub.startswith("tcp://0.0.0.0:")
    assert " ".join(a for k, a in final if k == "EXPOSE").split() == [cfg.publisher.pub.rsplit(":", 1)[1]]
    assert dict(final)["STOPSIGNAL"] == "SIGTERM"
    # a host .venv copied into the build stage would be built into the wheel's context
    assert ".venv" in (REPO / ".dockerignore").read_text().split()
