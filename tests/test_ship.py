"""Shipping: the production Dockerfile (read here; `make image-check` builds and runs it
where a container engine is installed) and the wheel, built here and run from outside the
checkout with its configs as package data."""

from __future__ import annotations

import json
import re
import shutil
import subprocess
import sys
import zipfile

import pytest
from fluidsense.controller.config import load_cell_config
from support.harness import REPO


def dockerfile() -> list[tuple[str, str]]:
    """(INSTRUCTION, arguments), continuation lines joined."""
    text = re.sub(r"\\\n", " ", (REPO / "Dockerfile").read_text())
    return [(line.split(None, 1)[0].upper(), line.split(None, 1)[1].strip())
            for line in text.splitlines() if line.strip() and not line.lstrip().startswith("#")]


def final_stage(steps):
    starts = [i for i, (k, _) in enumerate(steps) if k == "FROM"]
    return steps[starts[-1]:]


def test_the_image_is_multi_stage_non_root_with_a_healthcheck_and_no_test_extras():
    steps = dockerfile()
    froms = [a for k, a in steps if k == "FROM"]
    assert len(froms) == 2 and froms[0].endswith(" AS build"), froms
    final = final_stage(steps)
    # the base image satisfies requires-python
    version = re.search(r"python:(\d+)\.(\d+)", froms[-1])
    required = re.search(r'requires-python = ">=(\d+)\.(\d+)"', (REPO / "pyproject.toml").read_text())
    assert version and required and tuple(map(int, version.groups())) >= tuple(map(int, required.groups()))
    # runtime dependencies only: the wheels built in the first stage, nothing from the sources
    runs = " ".join(a for k, a in final if k == "RUN")
    assert "--no-index" in runs and "pip install" in runs
    assert "[test]" not in (REPO / "Dockerfile").read_text() and "make" not in runs.split()
    copies = [a for k, a in final if k == "COPY"]
    assert any(c.startswith("--from=build ") for c in copies)
    assert not any(c.split()[0] in (".", "./") for c in copies), "the final stage copies the source tree"
    # a user of its own, set after every RUN (root only while installing)
    users = [i for i, (k, _) in enumerate(final) if k == "USER"]
    assert users and final[users[-1]][1] not in ("root", "0", "0:0")
    assert max(i for i, (k, _) in enumerate(final) if k == "RUN") < users[-1]
    # the health check asks the command socket
    health = dict(final)["HEALTHCHECK"]
    cmd = json.loads(health.split("CMD", 1)[1])
    assert cmd[:3] == ["fluidsense", "cmd", "status"]
    # config and recordings are volumes; the default cell exists, validates, and records into one
    volumes = json.loads(dict(final)["VOLUME"])
    run = json.loads(dict(final)["CMD"])
    assert run[:3] == ["fluidsense", "run", "--config"] and run[3].startswith(volumes[0] + "/")
    source = next(a.split()[0] for k, a in final if k == "COPY" and a.split()[-1] == run[3])
    cfg = load_cell_config(REPO / source)
    assert cfg.driver.kind == "sim" and cfg.recording.enabled and not cfg.recording.dir.startswith("/")
    assert dict(final)["WORKDIR"] + "/" + cfg.recording.dir in volumes
    assert cfg.publisher.cmd.startswith("tcp://127.0.0.1:") and cfg.publisher.pub.startswith("tcp://0.0.0.0:")
    assert " ".join(a for k, a in final if k == "EXPOSE").split() == [cfg.publisher.pub.rsplit(":", 1)[1]]
    assert dict(final)["STOPSIGNAL"] == "SIGTERM"
    # a host .venv copied into the build stage would be built into the wheel's context
    assert ".venv" in (REPO / ".dockerignore").read_text().split()


@pytest.fixture(scope="module")
def wheel(tmp_path_factory):
    out = tmp_path_factory.mktemp("wheel")
    subprocess.run([sys.executable, "-m", "pip", "wheel", "--no-deps", "--quiet", "--wheel-dir", str(out), str(REPO)],
                   check=True, capture_output=True, timeout=600)
    (path,) = out.glob("fluidsense-*.whl")
    return path


PARTS = ("cli", "client", "common", "config", "controller", "daemon", "drivers", "simulator", "tasks")


def test_the_wheel_is_one_package_with_its_parts_and_configs_and_no_studies(wheel):
    """One top-level name (``fluidsense``); every module of the product's folders inside it,
    the shipped YAML as package data; nothing of lab/, tests/ or setup.py."""
    names = set(zipfile.ZipFile(wheel).namelist())
    assert {n.split("/")[0] for n in names} == {"fluidsense", wheel.name.split("-py3")[0] + ".dist-info"}
    for part in PARTS:
        modules = {f"fluidsense/{p.relative_to(REPO).as_posix()}" for p in (REPO / part).rglob("*.py")}
        assert modules and modules <= names, sorted(modules - names)
    for pattern in ("cell-*.yaml", "profiles/*.yaml", "tasks/*.yaml", "calibrations/*.json", "systemd/*"):
        shipped = {"fluidsense/config/" + p.relative_to(REPO / "config").as_posix()
                   for p in (REPO / "config").glob(pattern)}
        assert shipped and shipped <= names, shipped - names
    assert {"fluidsense/__init__.py", "fluidsense/__main__.py"} <= names
    assert not [n for n in names if n.startswith(("fluidsense/lab/", "fluidsense/tests/")) or n == "fluidsense/setup.py"]


def test_the_installed_wheel_runs_outside_the_checkout_beside_a_users_own_modules(wheel, tmp_path):
    """Installed without its dependencies (they are this venv's) into a directory first on
    the path, run from a folder that holds a user's own ``common.py`` and ``config.py`` (names
    a robot workspace is full of): the package, its configs and its client come from the
    wheel, and the user's modules stay theirs."""
    site, cwd = tmp_path / "site", tmp_path / "elsewhere"
    cwd.mkdir()
    (cwd / "common.py").write_text("WHO = 'the user'\n")
    (cwd / "config.py").write_text("WHO = 'the user'\n")
    subprocess.run([sys.executable, "-m", "pip", "install", "--no-deps", "--quiet", "--target", str(site), str(wheel)],
                   check=True, capture_output=True, timeout=600)
    assert sorted(p.name for p in site.iterdir() if not p.name.endswith(".dist-info")) == ["bin", "fluidsense"]
    env = {"PYTHONPATH": str(site), "PATH": "/usr/bin"}
    probe = ("import common, config, fluidsense, json; from fluidsense.daemon import app; "
             "from fluidsense.client import Gripper; cfg = app.load(None); "
             "print(json.dumps([fluidsense.__file__, str(app.default_config_path()), cfg.profile.name, "
             "str(app.TASKS_DIR / 'sorting.yaml'), common.WHO, config.WHO, Gripper.__module__]))")
    out = subprocess.run([sys.executable, "-c", probe], cwd=cwd, env=env, capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr
    module, config, profile, task, common_who, config_who, client = json.loads(out.stdout)
    assert module.startswith(str(site)) and config.startswith(str(site)) and task.startswith(str(site))
    assert profile and (site / "fluidsense" / "config" / "tasks" / "sorting.yaml").is_file()
    assert common_who == config_who == "the user" and client == "fluidsense.client.sync"
    usage = subprocess.run([sys.executable, "-m", "fluidsense", "--help"], cwd=cwd, env=env, capture_output=True,
                           text=True, timeout=120)
    assert usage.returncode == 0 and "usage: fluidsense" in usage.stdout and "bench" not in usage.stdout
    demo = subprocess.run([sys.executable, "-m", "fluidsense", "demo", "--json", "--cycles", "3"], cwd=cwd, env=env,
                          capture_output=True, text=True, timeout=300)
    assert demo.returncode == 0, demo.stderr
    assert json.loads(demo.stdout)


@pytest.mark.skipif(shutil.which("systemd-analyze") is None, reason="systemd-analyze is not installed")
def test_the_device_drop_in_verifies_and_keeps_the_hardening(tmp_path):
    """The drop-in's settings added at the end of the unit's [Service] (a later assignment
    wins, as a drop-in's does), verified with /opt/fluidsense pointing at this checkout."""
    unit_text = (REPO / "config/systemd/fluidsense.service").read_text().replace("/opt/fluidsense", str(REPO))
    drop_in = (REPO / "config/systemd/fluidsense-devices.conf").read_text()
    assert "PrivateDevices=no" in drop_in and "DevicePolicy=closed" in drop_in
    kept = ("NoNewPrivileges=yes", "ProtectSystem=strict", "ProtectHome=yes", "PrivateTmp=yes")
    assert all(k in unit_text for k in kept) and not any(k.split("=")[0] + "=" in drop_in for k in kept)
    unit = tmp_path / "fluidsense.service"
    settings = "\n".join(line for line in drop_in.splitlines() if not line.startswith("["))
    unit.write_text(unit_text.replace("\n[Install]", "\n" + settings + "\n\n[Install]", 1))
    assert "DevicePolicy=closed" in unit.read_text()
    out = subprocess.run(["systemd-analyze", "verify", "--man=no", str(unit)], capture_output=True, text=True,
                         timeout=60)
    problems = [line for line in (out.stdout + out.stderr).splitlines() if "fluidsense.service" in line]
    assert out.returncode == 0 and not problems, out.stdout + out.stderr
