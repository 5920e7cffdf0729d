"""Config-file fuzz: hostile YAML and bytes against the loaders of cell configs,
profiles and task files.

Each case is one file (and, for a cell config, sometimes the profile it names): random
bytes and text, nesting thousands deep, alias bombs, duplicate keys, special files (a
FIFO, ``/dev/zero``, a directory, a file larger than the cap) and the shipped configs
with one field replaced by a hostile value (a string for a number, a boolean, NaN,
infinity, huge numbers, NUL, containers), deleted or joined by an unknown one. Loading
must either give a valid config or a ConfigError whose every line names one of the
case's files (``FILE: field: reason``); anything else is a crash, and a load that does
not end is a hang.

``hostile_cases()`` is the hypothesis strategy (tests/unit/test_hostile_files.py runs it at a
small budget in the suite); ``fuzz_config_files(examples, seed)`` runs it at a large one,
each load in a worker process watched with a timeout, and returns the counts.
"""

from __future__ import annotations

import copy
import functools
import json
import os
import select
import subprocess
import sys
import tempfile
import time
import traceback
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import yaml

from lab import CONFIG, REPO

SPECIAL = ("fifo", "directory", "devzero", "huge", "missing")


@dataclass(frozen=True)
class Case:
    """One file to load: ``loader`` is cell, profile or task; ``text`` its bytes, or
    ``special`` names what stands in its place; ``profile`` the bytes of a profile.yaml
    next to it, or ``profile_special`` what stands there instead."""

    label: str
    loader: str
    text: bytes = b""
    special: str | None = None
    profile: bytes | None = None
    profile_special: str | None = None


@functools.cache
def bases() -> list[tuple[str, dict[str, Any]]]:
    """The shipped configs as documents that load from a case's directory."""
    out: list[tuple[str, dict[str, Any]]] = []
    for name in ("cell-sim.yaml", "cell-ur-sim.yaml", "cell-modbus-sim.yaml", "cell-ripeness-sim.yaml"):
        data = yaml.safe_load((CONFIG / name).read_text())
        data["profile"] = str((CONFIG / data["profile"]).resolve())
        out.append(("cell", data))
    inline = yaml.safe_load((CONFIG / "cell-sim.yaml").read_text())
    inline["profile"] = yaml.safe_load((CONFIG / "profiles" / "pneunet-gripper.yaml").read_text())
    out.append(("cell", inline))
    for path in sorted((CONFIG / "profiles").glob("*.yaml")):
        out.append(("profile", yaml.safe_load(path.read_text())))
    for path in sorted((CONFIG / "tasks").glob("*.yaml")):
        data = yaml.safe_load(path.read_text())
        data["cell"] = "cell.yaml"  # written next to the case
        out.append(("task", data))
    return out


def _dump(data: Any) -> bytes:
    return yaml.safe_dump(data, allow_unicode=True, sort_keys=False).encode()


# pieces of YAML syntax (and characters YAML forbids or treats specially) for random text
YAML_CHARS = list("{}[]:,-&*!|>'\"#%@`?~ \n\t\\ab01.eE+") + ["\0", "\x85", "\ufeff", "é", ".nan", ".inf", "<<"]


def cell_text(profile: str | None = None) -> bytes:
    """The simulated cell config (with its profile, or naming ``profile``)."""
    data = bases()[0][1]
    return _dump(data if profile is None else dict(data, profile=profile))


def _paths(node: Any, prefix: tuple = ()) -> list[tuple]:
    out = [prefix]
    if isinstance(node, dict):
        for key, value in node.items():
            out += _paths(value, (*prefix, key))
    elif isinstance(node, list):
        for i, value in enumerate(node):
            out += _paths(value, (*prefix, i))
    return out


def hostile_cases():
    """The hypothesis strategy of hostile cases. Hypothesis is imported here, not at the
    top: it is a test dependency, and ``python -m lab bench`` imports every bench module."""
    from hypothesis import strategies as st

    loaders = st.sampled_from(["cell", "profile", "task"])
    hostile_value = st.one_of(
        st.sampled_from(["63", "1e3", "", " ", "\0", "a\0b", "/dev/zero", "x" * 10_000, "tcp://127.0.0.1:99999",
                         "tcp://127.0.0.1:*", "ipc://", True, False, None, float("nan"), float("inf"),
                         -float("inf"), 10**30, -(10**30), 10**400, 1e-300, 1e300, 0, -1, 99999, [], {}, [[[]]],
                         {"kind": "plc"}]),
        st.floats(allow_nan=True, allow_infinity=True),
        st.integers(min_value=-(10**60), max_value=10**60),
        st.text(max_size=30),
        st.lists(st.integers(-5, 5), max_size=4),
        st.dictionaries(st.text(max_size=6), st.integers(-5, 5), max_size=3),
    )

    @st.composite
    def mutated(draw) -> Case:
        """A shipped config with one field replaced, deleted or joined by an unknown one."""
        loader, base = draw(st.sampled_from(bases()))
        data = copy.deepcopy(base)
        path = draw(st.sampled_from(_paths(data)))
        op = draw(st.sampled_from(["replace", "replace", "delete", "add"]))
        value = draw(hostile_value)
        if not path:
            data = value if op == "replace" else data
        else:
            parent = data
            for part in path[:-1]:
                parent = parent[part]
            if op == "replace":
                parent[path[-1]] = value
            elif op == "delete":
                del parent[path[-1]]
            elif isinstance(parent, dict):
                parent[draw(st.text(min_size=1, max_size=8))] = value
            else:
                parent.append(value)
        return Case(f"mutated/{op}", loader, _dump(data))

    @st.composite
    def duplicated(draw) -> Case:
        """A shipped config with one of its lines repeated (a key twice, or a list item)."""
        loader, base = draw(st.sampled_from(bases()))
        lines = _dump(base).decode().splitlines(keepends=True)
        i = draw(st.integers(0, len(lines) - 1))
        return Case("duplicate line", loader, "".join(lines[: i + 1] + lines[i:]).encode())

    @st.composite
    def deep(draw) -> Case:
        depth = draw(st.integers(1, 5000))
        kind = draw(st.sampled_from(["flow-list", "flow-map", "block-list", "map-in-list"]))
        body = {"flow-list": "[" * depth + "]" * depth, "flow-map": "{a: " * depth + "1" + "}" * depth,
                "block-list": "- " * depth + "1", "map-in-list": "[{a: " * depth + "1" + "}]" * depth}[kind]
        return Case(f"deep/{kind}", draw(loaders), f"driver: {body}\n".encode())

    @st.composite
    def alias_bomb(draw) -> Case:
        levels, width = draw(st.integers(1, 12)), draw(st.integers(2, 12))
        lines = ["a0: &a0 [" + ", ".join(["lol"] * width) + "]"]
        lines += [f"a{k}: &a{k} [" + ", ".join([f"*a{k - 1}"] * width) + "]" for k in range(1, levels)]
        lines.append(f"driver: *a{levels - 1}")
        if draw(st.booleans()):  # an alias inside its own anchor
            lines.append("profile: &self [1, *self]")
        return Case("aliases", draw(loaders), ("\n".join(lines) + "\n").encode())

    @st.composite
    def special(draw) -> Case:
        what = draw(st.sampled_from(SPECIAL))
        if draw(st.booleans()):
            return Case(f"special/{what}", draw(loaders), special=what)
        return Case(f"special profile/{what}", "cell", cell_text("profile.yaml"), profile_special=what)

    return st.one_of(
        mutated(), mutated(), mutated(),  # the likeliest mistakes: a valid config with one field wrong
        duplicated(),
        deep(),
        alias_bomb(),
        special(),
        st.builds(lambda b, k: Case("random bytes", k, b), st.binary(max_size=2048), loaders),
        st.builds(lambda t, k: Case("random YAML-ish text", k, t.encode("utf-8", "surrogatepass")),
                  st.lists(st.sampled_from(YAML_CHARS), max_size=300).map("".join), loaders),
        st.builds(lambda p: Case("cell with a hostile profile", "cell", cell_text("profile.yaml"), profile=p),
                  st.one_of(mutated().map(lambda c: c.text), st.binary(max_size=512))),
    )


def _place(path: Path, what: str | None, text: bytes | None) -> None:
    if what is None:
        path.write_bytes(text or b"")
    elif what == "fifo":
        os.mkfifo(path)
    elif what == "directory":
        path.mkdir()
    elif what == "devzero":
        path.symlink_to("/dev/zero")
    elif what == "huge":  # sparse: larger than any config may be, without using the disk
        with open(path, "wb") as f:
            f.truncate(64 * 2**20)
    # "missing": nothing there


def write(case: Case, directory: Path) -> Path:
    """The case's files in ``directory`` (empty); returns the file to load."""
    main = directory / "case.yaml"
    _place(main, case.special, case.text)
    if case.profile is not None or case.profile_special is not None:
        _place(directory / "profile.yaml", case.profile_special, case.profile)
    if case.loader == "task":
        (directory / "cell.yaml").write_bytes(cell_text())
    return main


def load(path: Path, loader: str) -> None:
    from fluidsense.controller.config import load_cell_config, load_profile
    from fluidsense.tasks.config import cell_path, load_task

    if loader == "cell":
        load_cell_config(path)
    elif loader == "profile":
        load_profile(path)
    else:
        cell_path(path, load_task(path))


def outcome(path: Path, loader: str) -> tuple[str, str]:
    """("loaded" | "rejected" | "bad message" | "crash", detail) of loading ``path``."""
    from fluidsense.common.errors import ConfigError

    try:
        load(path, loader)
    except ConfigError as exc:
        lines = str(exc).splitlines()
        names = (str(path.parent) + os.sep,)
        good = bool(lines) and all(line.startswith(names) and ": " in line and line.split(": ", 1)[1].strip()
                                   for line in lines)
        return ("rejected" if good else "bad message"), str(exc)[:500]
    except Exception as exc:  # noqa: BLE001 - what the fuzz is looking for
        return "crash", "".join(traceback.format_exception_only(exc)).strip()[:500] + " | " + \
            traceback.format_tb(exc.__traceback__)[-1].strip()[:300]
    return "loaded", ""


# ------------------------------------------------------------------ at a large budget
PER_FILE_TIMEOUT_S = 10.0


def _generate(examples: int, seed: int) -> list[Case]:
    from hypothesis import HealthCheck, Phase, given, settings
    from hypothesis import seed as with_seed

    cases: list[Case] = []

    @with_seed(seed)
    @settings(max_examples=examples, database=None, deadline=None, phases=[Phase.generate],
              suppress_health_check=list(HealthCheck))
    @given(case=hostile_cases())
    def collect(case: Case) -> None:
        cases.append(case)

    collect()
    return cases


def _worker(manifest: str) -> None:
    """Load each case of the manifest in order; one JSON line per case on stdout."""
    import resource

    limit = 4 * 2**30  # a memory bomb is a crash here, not a machine out of memory
    resource.setrlimit(resource.RLIMIT_AS, (limit, limit))
    for i, (path, loader) in enumerate(json.loads(Path(manifest).read_text())):
        result, detail = outcome(Path(path), loader)
        sys.stdout.write(json.dumps({"i": i, "outcome": result, "detail": detail}) + "\n")
        sys.stdout.flush()


def _run_from(manifest: Path, start: int, results: dict[int, tuple[str, str]], total: int) -> int:
    """Run the worker on cases ``start``..; returns the index it got stuck on (or total)."""
    sub = json.loads(manifest.read_text())[start:]
    part = manifest.with_name(f"part-{start}.json")
    part.write_text(json.dumps(sub))
    # the worker runs in the cases' folder (relative paths stay there): the lab from the checkout
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(filter(None, (str(REPO), os.environ.get("PYTHONPATH"))))}
    proc = subprocess.Popen([sys.executable, "-m", "lab.bench.fuzz_files", "--worker", str(part)],
                            stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, cwd=manifest.parent, env=env)
    buf, i = b"", start
    try:
        while i < total:
            ready, _, _ = select.select([proc.stdout], [], [], PER_FILE_TIMEOUT_S)
            if not ready:
                results[i] = ("hang", f"no result within {PER_FILE_TIMEOUT_S:g} s")
                return i + 1
            chunk = os.read(proc.stdout.fileno(), 65536)
            if not chunk:  # the worker died (a crash in C, the memory limit)
                results[i] = ("crash", f"the worker process died (exit {proc.wait()})")
                return i + 1
            buf += chunk
            while b"\n" in buf:
                line, buf = buf.split(b"\n", 1)
                got = json.loads(line)
                results[start + got["i"]] = (got["outcome"], got["detail"])
                i = start + got["i"] + 1
        return total
    finally:
        proc.kill()
        proc.wait()
        proc.stdout.close()


def fuzz_config_files(examples: int, seed: int) -> dict[str, Any]:
    """Generate ``examples`` hostile config files (seeded), load each in a worker process
    (a load that gives no result within PER_FILE_TIMEOUT_S is a hang), and count."""
    t0 = time.perf_counter()
    cases = _generate(examples, seed)
    results: dict[int, tuple[str, str]] = {}
    with tempfile.TemporaryDirectory(prefix="fluidsense-fuzz-") as tmp:
        entries = []
        for i, case in enumerate(cases):
            directory = Path(tmp) / f"{i:06d}"
            directory.mkdir()
            entries.append((str(write(case, directory)), case.loader))
        manifest = Path(tmp) / "manifest.json"
        manifest.write_text(json.dumps(entries))
        start = 0
        while start < len(cases):
            start = _run_from(manifest, start, results, len(cases))
    counts = {k: sum(1 for r, _ in results.values() if r == k)
              for k in ("rejected", "loaded", "bad message", "crash", "hang")}
    bad = [{"label": cases[i].label, "loader": cases[i].loader, "outcome": r, "detail": d,
            "file": cases[i].text[:200].decode("utf-8", "replace")}
           for i, (r, d) in sorted(results.items()) if r in ("bad message", "crash", "hang")]
    by_label: dict[str, int] = {}
    for case in cases:
        by_label[case.label] = by_label.get(case.label, 0) + 1
    return {"files": len(cases), "rejected_cleanly": counts["rejected"], "loaded": counts["loaded"],
            "crashes": counts["crash"] + counts["bad message"], "hangs": counts["hang"],
            "examples_of_crashes": bad[:20], "by_kind": dict(sorted(by_label.items())),
            "seed": seed, "seconds": round(time.perf_counter() - t0, 1)}


if __name__ == "__main__":
    if sys.argv[1:2] == ["--worker"]:
        _worker(sys.argv[2])
    else:  # python -m fluidsense.bench.fuzz_files [EXAMPLES] [SEED]
        args = [int(a) for a in sys.argv[1:3]]
        print(json.dumps(fuzz_config_files(*(args + [2000, 1][len(args):])), indent=2))
