"""The run half of `make image-check` (the Makefile builds the image, then runs this with
the host's venv): start the production image as a robot PC would, with a config volume and
a runs volume from the host, and check what a deployment relies on. Prints one line per
check, then the image's size and the start-up time; exits 1 on the first failed check.

    python tests/support/image_check.py --engine podman --run-flags "..." IMAGE

The mounted config is the image's own default cell (the simulated cell in real time) with
another shipped profile, and with the command socket on every interface of the container,
so that the published port reaches it: that needs CURVE keys (the daemon refuses a command
socket off loopback without them), made on the host by `fluidsense keys`. The server's
secret key belongs to the container's user; everything else in the volume is root's and
world-readable, as in /etc.
"""

from __future__ import annotations

import argparse
import json
import os
import re
import shlex
import shutil
import subprocess
import sys
import tempfile
import time
import tomllib
from pathlib import Path

import yaml
from fluidsense.client import GRIPPER_TOPICS, Gripper, NoReply, Refused
from fluidsense.config import SHIPPED

REPO = Path(__file__).resolve().parents[2]
CLI = Path(sys.executable).with_name("fluidsense")  # the host venv's
CONFIG, RUNS = "/etc/fluidsense", "/var/lib/fluidsense/runs"  # the image's volumes
PUB_PORT, CMD_PORT = 5560, 5561
PROFILE = "pneunet-gripper-quick"  # not the image's default (pneunet-gripper): proves the volume was read
START_S, STOP_S, CYCLE_S = 180, 60, 120  # bounds, not expectations


class Failed(Exception):
    pass


def check(ok: bool, what: str, detail: object = "") -> None:
    if not ok:
        raise Failed(f"{what}: {detail}" if detail != "" else what)
    print(f"image-check: ok: {what}", flush=True)


class Engine:
    def __init__(self, engine: str, run_flags: str):
        self.cmd, self.run_flags = shlex.split(engine), shlex.split(run_flags)

    def __call__(self, *args: str, timeout: float = 120, check: bool = True) -> subprocess.CompletedProcess:
        out = subprocess.run([*self.cmd, *args], capture_output=True, text=True, timeout=timeout)
        if check and out.returncode != 0:
            raise Failed(f"{' '.join(self.cmd[:1] + list(args[:2]))}: exit {out.returncode}: {out.stderr.strip()[-2000:]}")
        return out

    def run(self, image: str, *args: str, entrypoint: str | None = None, volumes: tuple[str, ...] = (),
            timeout: float = 120) -> str:
        """A one-off container of the image (removed after), as the image's user; no health
        check (podman would try to schedule it with systemd's timers)."""
        ep = ["--entrypoint", entrypoint] if entrypoint else []
        vols = [f"--volume={v}" for v in volumes]
        return self("run", "--rm", "--no-healthcheck", *self.run_flags, *vols, *ep, image, *args,
                    timeout=timeout).stdout

    def inspect(self, what: str, kind: str = "container") -> dict:
        return json.loads(self(kind, "inspect", what).stdout)[0]


def normal(name: str) -> str:
    return re.sub(r"[-_.]+", "-", name).lower()


# the distributions fluidsense needs (its requirements, followed; extras not taken), and what
# is installed, read inside the image with its own Python
CLOSURE = r"""
import importlib.metadata as m, json, re
norm = lambda n: re.sub(r"[-_.]+", "-", n).lower()
need, todo = set(), ["fluidsense"]
while todo:
    name = todo.pop()
    if name in need:
        continue
    try:
        reqs = m.requires(name) or []
    except m.PackageNotFoundError:  # a requirement for another platform (colorama on Windows)
        continue
    need.add(name)
    for req in reqs:
        if "extra" not in req.partition(";")[2]:
            todo.append(norm(re.split(r"[\s;<>=!~\[(]", req, maxsplit=1)[0]))
files = [str(f) for f in m.files("fluidsense")]
print(json.dumps({"need": sorted(need), "files": files}))
"""


def check_packages(engine: Engine, image: str) -> None:
    listed = {normal(p["name"]) for p in json.loads(engine.run(image, "list", "--format", "json", entrypoint="pip"))}
    extras = tomllib.loads((REPO / "pyproject.toml").read_text())["project"]["optional-dependencies"]["test"]
    test = {normal(re.split(r"[\s;<>=!~\[(]", r, maxsplit=1)[0]) for r in extras}
    check("fluidsense" in listed and not listed & test,
          f"pip list in the image: {len(listed)} distributions, none of the test extra's", sorted(listed & test))
    got = json.loads(engine.run(image, "-c", CLOSURE, entrypoint="python"))
    others = listed - set(got["need"]) - {"pip", "setuptools"}
    check(not others, "every distribution in the image is a runtime requirement of fluidsense (or pip)",
          sorted(others))
    studies = [f for f in got["files"] if f.startswith(("lab/", "tests/", "fluidsense/lab/", "fluidsense/tests/"))]
    check(not studies and any(f.startswith("fluidsense/daemon/") for f in got["files"]),
          "the installed wheel holds the product and no study or test", studies[:5])


def make_volumes(tmp: Path, uid: int) -> tuple[Path, Path, tuple[str, str]]:
    """The config volume (root's, world-readable, the server's secret key the container
    user's) and the runs volume (the container user's)."""
    conf, runs = tmp / "etc-fluidsense", tmp / "runs"
    conf.mkdir(mode=0o755)
    conf.chmod(0o755)
    for part in ("profiles", "tasks"):
        shutil.copytree(SHIPPED / part, conf / part)
    keys = subprocess.run([str(CLI), "keys", str(conf / "keys")], capture_output=True, text=True, timeout=60)
    check(keys.returncode == 0, "fluidsense keys on the host", keys.stderr)
    os.chown(conf / "keys" / "server.key_secret", uid, uid)
    cell = yaml.safe_load((SHIPPED / "cell-sim-container.yaml").read_text())
    cell["profile"] = f"profiles/{PROFILE}.yaml"
    # Containers here get no real-time budget (cgroup v1 with real-time group scheduling: podman's
    # cgroup has cpu.rt_runtime_us 0), so the sample loop runs at normal priority, and beside a busy
    # suite it fell 0.35 s behind its samples: an overrun fault at the default 0.25 s. What this
    # checks is the deployment, not timing (the benches measure that): allow 5 s.
    cell["supervision"] = {"overrun_s": 5.0, "no_data_s": 5.0}
    cell["publisher"]["cmd"] = f"tcp://0.0.0.0:{CMD_PORT}"
    cell["publisher"]["cmd_curve"] = {"server_secret_file": f"{CONFIG}/keys/server.key_secret",
                                      "clients_dir": f"{CONFIG}/keys/clients"}
    (conf / "cell.yaml").write_text(yaml.safe_dump(cell, sort_keys=False))
    runs.mkdir(mode=0o750)
    os.chown(runs, uid, uid)
    return conf, runs, (str(conf / "keys" / "client.key_secret"), str(conf / "keys" / "server.key"))


def health(engine: Engine, name: str) -> str | None:
    state = engine.inspect(name)["State"]
    return (state.get("Health") or state.get("Healthcheck") or {}).get("Status")


def run_container(engine: Engine, image: str, tmp: Path, uid: int) -> float:
    conf, runs, curve = make_volumes(tmp, uid)
    name = f"fluidsense-check-{os.getpid()}"
    t0 = time.monotonic()
    volumes = (f"{conf}:{CONFIG}:ro", f"{runs}:{RUNS}")
    engine("run", "--detach", "--replace", "--name", name, *engine.run_flags,
           "--publish", f"127.0.0.1::{PUB_PORT}", "--publish", f"127.0.0.1::{CMD_PORT}",
           *(f"--volume={v}" for v in volumes), image)
    try:
        ports = {p: engine("port", name, f"{p}/tcp").stdout.split()[0].rsplit(":", 1)[1] for p in (PUB_PORT, CMD_PORT)}
        cmd, pub = f"tcp://127.0.0.1:{ports[CMD_PORT]}", f"tcp://127.0.0.1:{ports[PUB_PORT]}"
        # started: the first status, through the published ports, of a daemon that samples
        with Gripper(cmd, pub, curve=curve, timeout_s=5, event_timeout_s=CYCLE_S,
                     topics=(*GRIPPER_TOPICS, "fault", "log")) as g:
            deadline = t0 + START_S
            while True:
                if not engine.inspect(name)["State"]["Running"]:
                    raise Failed(f"the container stopped while starting: {engine('logs', name).stderr[-3000:]}")
                try:
                    g.attach(1)
                    status = g.status()
                except (NoReply, Refused):  # not up yet, or still connecting
                    status = None
                if status and status["state"] == "idle" and status["samples"] > 0:
                    startup_s = time.monotonic() - t0
                    break
                if time.monotonic() > deadline:
                    raise Failed(f"no sampling daemon within {START_S} s: {engine('logs', name).stderr[-3000:]}")
                time.sleep(0.1)
            check(status["backend"] == "sim" and not status["virtual"] and status["profile"] == PROFILE,
                  f"the daemon runs on the simulated cell in real time with the mounted config's profile "
                  f"({PROFILE}), {startup_s:.1f} s after `run`", {k: status[k] for k in ("backend", "virtual", "profile")})
            pid = engine.inspect(name)["State"]["Pid"]
            ids = re.search(r"^Uid:\s+(.*)$", Path(f"/proc/{pid}/status").read_text(), re.M).group(1).split()
            argv = Path(f"/proc/{pid}/cmdline").read_bytes().split(b"\0")
            check(set(ids) == {str(uid)} and uid != 0 and b"run" in argv and argv[1].endswith(b"/fluidsense"),
                  f"the daemon (host pid {pid}) is `fluidsense run` as uid {uid}, not root", (ids, argv))
            cli = subprocess.run([str(CLI), "cmd", "status", "--endpoint", cmd, "--client-key", curve[0],
                                  "--server-key", curve[1], "--timeout", "10"], capture_output=True, text=True,
                                 timeout=60)
            check(cli.returncode == 0 and json.loads(cli.stdout)["ok"],
                  f"`fluidsense cmd status` from the host answers through the published command port ({cmd}, CURVE)",
                  cli.stderr or cli.stdout)
            hc = engine("healthcheck", "run", name, check=False, timeout=60)
            check(hc.returncode == 0 and health(engine, name) == "healthy",
                  "the engine's healthcheck (the image's HEALTHCHECK) reports healthy",
                  (hc.returncode, hc.stdout, hc.stderr[-500:], health(engine, name)))
            # a robot program's first cycles: the free-air reference with the gripper empty, then a grasp
            g.scene({"kind": "none"})
            g.measure(store_reference=True)
            g.scene({"kind": "cylinder", "diameter_mm": 60})
            grasp = g.measure()
            check(grasp.object is True, f"sensing cycles commanded from the host: the reference, then cycle "
                  f"{grasp.cycle_id} grasps the 60 mm cylinder and opens again", grasp)
            recordings = sorted(runs.glob("*.mcap"))
            check(len(recordings) == 1 and recordings[0].stat().st_uid == uid,
                  f"the recording appears on the host in the runs volume, written by uid {uid}",
                  [(p.name, p.stat().st_uid) for p in recordings])
            t_stop = time.monotonic()
            engine("stop", "--time", str(STOP_S), name, timeout=STOP_S + 60)  # the image's STOPSIGNAL
            stop_s = time.monotonic() - t_stop
            state = engine.inspect(name)["State"]
            check(state["ExitCode"] == 0 and not state.get("OOMKilled"),
                  f"SIGTERM (`stop`) ends the daemon with exit 0 in {stop_s:.1f} s", state.get("ExitCode"))
            last = None
            while (ev := g.next_event(10)) is not None:  # what came out of the published port until the end
                if ev.topic == "log" and ev.data.get("message") == "controller stopped":
                    last = ev.data
            check(last is not None and last["safe"] is True and last["valves"],
                  "its last message, through the published event port: `controller stopped`, valves safe", last)
        # replayed by the image's own fluidsense, where the recorded config's key files are
        replay = json.loads(engine.run(image, "replay", f"{RUNS}/{recordings[0].name}", "--json",
                                       entrypoint="fluidsense", volumes=volumes))
        cycles = replay["cycles"]
        check(replay["closed"] and replay["samples"] > 0 and len(cycles) == 2
              and all(c["status"] == "complete" for c in cycles)
              and replay["agree"], f"the recording is closed and holds both cycles ({replay['samples']} samples), "
              "which its replay recomputes alike", {k: replay[k] for k in ("closed", "samples", "agree", "cycles")})
        return startup_s
    finally:
        engine("rm", "--force", name, check=False)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("image")
    p.add_argument("--engine", default="podman", help="the engine's command (default podman)")
    p.add_argument("--run-flags", default="", help="flags for every `run` (the Makefile's ENGINE_FLAGS)")
    p.add_argument("--base", help="the base image, for its size")
    args = p.parse_args(argv)
    engine = Engine(args.engine, args.run_flags)
    try:
        config = engine.inspect(args.image, "image")["Config"]
        uid = int(engine.run(args.image, "-u", entrypoint="id"))
        check(uid != 0 and config.get("User") not in (None, "", "root", "0"),
              f"the image runs as its own user ({config.get('User')}, uid {uid})")
        check_packages(engine, args.image)
        with tempfile.TemporaryDirectory(prefix="fluidsense-image-check.") as tmp:
            startup_s = run_container(engine, args.image, Path(tmp), uid)
    except (Failed, subprocess.TimeoutExpired) as exc:
        print(f"image-check: FAILED: {exc}", file=sys.stderr)
        return 1
    size = engine.inspect(args.image, "image")["Size"]
    base = f" (base {engine.inspect(args.base, 'image')['Size'] / 1e6:.0f} MB)" if args.base else ""
    print(f"image-check: image size {size / 1e6:.0f} MB{base}; start-up {startup_s:.1f} s "
          f"(`run` to the first status of a sampling daemon through the published command port)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
