"""Shipping: the production Dockerfile (read here, and built and run by `make image-check`
where podman is installed), the wheel (built here and run from outside the checkout with
its configs as package data), and docs/deployment.md's install from that wheel, run in a
scratch root, whose unit systemd-analyze verifies and which agrees with the image.

(Its in-process tests: tests/unit/test_ship.py.)
"""

from __future__ import annotations

import json
import os
import re
import shlex
import shutil
import subprocess
import sys
import time
import zipfile
from pathlib import Path

import pytest
from fluidsense.controller.config import load_cell_config
from support.harness import REPO
from support.shipping import doc_block, dockerfile, stages, unit_entries

# pip builds the wheel and installs it, with its dependencies from PyPI, into scratch venvs
# (docs/deployment.md's install as written): minutes each on a loaded machine. The image's
# test names its own, longer bound.
pytestmark = pytest.mark.timeout(900)


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


# ------------------------------------------------------- the install from the wheel
def rooted(block: str, root: Path, wheel: Path) -> list[str]:
    """A block of docs/deployment.md made to run in ``root`` instead of ``/``: absolute
    paths under it, the wheel built here for the copied one, no ``useradd`` or ``systemctl``
    (users and services of this machine), and pip without dependencies (they come from the
    index: the image check installs them for real)."""
    out = []
    for line in block.splitlines():
        cmd = line.split(" #", 1)[0].strip()
        if not cmd or cmd.startswith("#") or cmd.split()[0] in ("useradd", "systemctl"):
            continue
        cmd = re.sub(r"(?<![\w.$/])/(opt|etc)/", lambda m: f"{root}/{m.group(1)}/", cmd)
        cmd = re.sub(r"\S*fluidsense-[\w.]+-py3-none-any\.whl", str(wheel), cmd)
        out.append(cmd.replace("/bin/pip install ", "/bin/pip install --no-deps "))
    return out


@pytest.fixture(scope="module")
def installed(wheel, tmp_path_factory) -> Path:
    """docs/deployment.md's install block, run for real in a scratch root."""
    root = tmp_path_factory.mktemp("root")
    (root / "etc" / "systemd" / "system").mkdir(parents=True)  # there on a robot PC
    script = rooted(doc_block("### Install on the robot PC"), root, wheel)
    assert any("bin/pip install --no-deps " + str(wheel) in line for line in script), script
    out = subprocess.run(["bash", "-euo", "pipefail", "-c", "\n".join(script)], capture_output=True, text=True,
                         timeout=600)
    assert out.returncode == 0, "\n".join(script) + "\n" + out.stderr
    return root


def test_the_docs_install_the_wheel_into_the_venv_the_unit_names_and_the_image_agrees(installed):
    """No clone, no test extras: the wheel into a venv, the unit and the config from the
    wheel; the installed unit runs that venv's fluidsense on the installed config, and the
    image has the same venv, command, working directory, user and recordings."""
    root, block = installed, doc_block("### Install on the robot PC")
    assert "git clone" not in block and "make install" not in block and "[test]" not in block
    unit = {k: v[-1] for k, v in unit_entries(root / "etc/systemd/system/fluidsense.service").items()}
    argv = shlex.split(unit["Service.ExecStart"])
    venv = re.search(r"^python3 -m venv (\S+)$", block, re.M).group(1)
    exe = root / argv[0].lstrip("/")
    assert argv[0] == venv + "/bin/fluidsense" and exe.is_file() and os.access(exe, os.X_OK)
    # the installed config validates, beside the profiles and tasks it names
    config, tasks = argv[argv.index("--config") + 1], argv[argv.index("--tasks-dir") + 1]
    cfg = load_cell_config(root / config.lstrip("/"))
    assert cfg.driver.kind == "sim" and cfg.driver.clock == "realtime" and cfg.recording.enabled
    assert (root / tasks.lstrip("/") / "sorting.yaml").is_file()
    # the service writes only in its state directory: its home, working directory and recordings
    state = "/var/lib/" + unit["Service.StateDirectory"]
    assert unit["Service.WorkingDirectory"] == state and cfg.recording.dir.startswith(state + "/")
    assert unit["Service.ProtectSystem"] == "strict" and "Service.ReadWritePaths" not in unit
    assert re.search(rf"^useradd .*--home-dir {state} .*{unit['Service.User']}$", block, re.M)
    # the image: the same venv on its PATH, the same command, directory, user and recordings
    by = stages(dockerfile())
    final = dict(by["final"])
    assert f"python3 -m venv {venv} " in " ".join(a for k, a in by["build"] if k == "RUN")
    assert dict(by["python"])["ENV"].startswith(f"PATH={venv}/bin:")
    assert json.loads(final["CMD"]) == ["fluidsense", *argv[1:]]
    assert final["WORKDIR"] == state and final["USER"] == unit["Service.User"]
    assert cfg.recording.dir in json.loads(final["VOLUME"]) and os.path.dirname(config) in json.loads(final["VOLUME"])


def systemd_units() -> Path:
    """This machine's systemd unit folder (the targets a service unit is ordered against)."""
    return next(p for p in (Path("/usr/lib/systemd/system"), Path("/lib/systemd/system"))
                if (p / "sysinit.target").exists())


def verify(root: Path) -> tuple[int, str]:
    out = subprocess.run(["systemd-analyze", "verify", "--man=no", f"--root={root}", "fluidsense.service"],
                         capture_output=True, text=True, timeout=60)
    return out.returncode, out.stdout + out.stderr


@pytest.mark.skipif(shutil.which("systemd-analyze") is None, reason="systemd-analyze is not installed")
def test_systemd_analyze_verifies_the_installed_unit_alone_and_with_the_devices_drop_in(installed, wheel):
    """`systemd-analyze verify --root` on the scratch root: the unit as installed (its
    ExecStart must exist there), then with the drop-in installed as the docs say."""
    root = installed
    shutil.copytree(systemd_units(), root / "usr/lib/systemd/system", dirs_exist_ok=True, symlinks=True)
    rc, out = verify(root)
    assert rc == 0 and "fluidsense" not in out, out
    # verify reads drop-ins under --root: a bad one is reported (then removed)
    bad = root / "etc/systemd/system/fluidsense.service.d/zz-bad.conf"
    bad.parent.mkdir(parents=True)
    bad.write_text("[Service]\nNoSuchSetting=1\n")
    assert "NoSuchSetting" in verify(root)[1]
    bad.unlink()
    # in the install's shell: $shipped is the installed package's config folder
    shipped = [line for line in rooted(doc_block("### Install on the robot PC"), root, wheel)
               if line.startswith("shipped=")]
    script = shipped + rooted(doc_block("**systemd.**"), root, wheel)
    out = subprocess.run(["bash", "-euo", "pipefail", "-c", "\n".join(script)], capture_output=True, text=True,
                         timeout=60)
    assert out.returncode == 0, out.stderr
    drop_in = (root / "etc/systemd/system/fluidsense.service.d/devices.conf").read_text()
    assert "PrivateDevices=no" in drop_in and "DevicePolicy=closed" in drop_in
    # the drop-in opens device nodes and nothing else of the hardening
    unit = unit_entries(root / "etc/systemd/system/fluidsense.service")
    kept = {"NoNewPrivileges": "yes", "ProtectSystem": "strict", "ProtectHome": "yes", "PrivateTmp": "yes"}
    assert all(unit[f"Service.{k}"] == [v] for k, v in kept.items())
    assert not any(f"\n{k}=" in drop_in for k in kept)
    rc, out = verify(root)
    assert rc == 0 and "fluidsense" not in out, out


# ------------------------------------------------------------------ the image, run
IMAGE_TOOLS = ("podman", "runc", "debootstrap")


def image_check_output() -> tuple[int, str]:
    """`make image-check`'s output and exit status: from the run `make test` started in the
    background beside the suite (FLUIDSENSE_IMAGE_CHECK_LOG; its last line is ``exit N``),
    or run here."""
    log = os.environ.get("FLUIDSENSE_IMAGE_CHECK_LOG")
    if not log:
        out = subprocess.run(["make", "--no-print-directory", "image-check"], cwd=REPO, capture_output=True,
                             text=True, timeout=3000)
        return out.returncode, out.stdout + out.stderr
    deadline = time.monotonic() + 3000
    while not re.search(r"^exit \d+$", text := Path(log).read_text(), re.M):
        assert time.monotonic() < deadline, f"make image-check did not end within 3000 s: {text[-3000:]}"
        time.sleep(1)
    return int(re.search(r"^exit (\d+)$", text, re.M).group(1)), text


# waits for `make image-check` started beside the suite (network and engine bound; its own 3000 s bound)
@pytest.mark.timeout(3600)
def test_the_image_builds_and_runs_as_a_deployment_relies_on():
    """The Dockerfile built by podman on a Debian base made here, then run with a config
    volume and a runs folder of the host (Makefile image-check; tests/support/image_check.py)."""
    missing = [tool for tool in IMAGE_TOOLS if shutil.which(tool) is None]
    if missing or os.geteuid() != 0:
        pytest.skip(f"{' '.join(missing) or 'root'} needed: the image is not built (make image-check installs them, "
                    "as root)")
    rc, text = image_check_output()
    assert rc == 0 and "image-check: FAILED" not in text, text[-6000:]
    done = re.findall(r"^image-check: ok: (.*)$", text, re.M)
    for what in ("its own user", "pip list in the image", "simulated cell in real time with the mounted config",
                 "not root", "`fluidsense cmd status` from the host answers through the published command port",
                 "healthcheck", "grasps the 60 mm cylinder", "runs volume", "ends the daemon with exit 0",
                 "valves safe", "the recording is closed"):
        assert any(what in line for line in done), (what, done)
    assert re.search(r"^image-check: image size \d+ MB .*; start-up [\d.]+ s", text, re.M), text[-2000:]
