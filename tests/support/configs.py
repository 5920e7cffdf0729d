"""The config builder: a shipped cell config, profile or task file with a test's
overrides merged in, checked by the project's own models and written into the test's
directory. A typo in an override (``supervison=``, ``driver={"no_data": 5}``) fails the
test at once with the file and field named, instead of a daemon that quietly ignores it
or fails later for another reason.

    cell_config(tmp_path, "cell-ur-sim", supervision={"no_data_s": 5}, driver={"arm": DELETE})
    cell_config(tmp_path, cell, gripper={"calibrations": ["other.json"]})   # a config already written
    profile_config(tmp_path, "pneunet-gripper", sequence={"charge_s": 0.5})
    task_config(tmp_path, "sorting", cell=str(cell), motion={"speed_m_s": 1.0})

Overrides merge key by key into mappings (``driver={"host": h}`` keeps the rest of the
driver); any other value replaces, and so does a mapping marked ``whole({...})``;
``DELETE`` removes the key. A test that writes a bad
config on purpose passes ``check=False``.
"""

from __future__ import annotations

import copy
import uuid
from pathlib import Path
from typing import Any

import yaml
from fluidsense.controller.config.cell import CellConfig, load_profile
from fluidsense.controller.config.gripper import resolve_calibrations
from fluidsense.controller.config.loading import validate
from fluidsense.controller.config.profile import Profile
from fluidsense.tasks.config import TaskDocument

REPO = Path(__file__).resolve().parents[2]
CONFIG = REPO / "config"

DELETE = object()  # an override value: remove this key


class whole(dict):  # noqa: N801 - reads as a marker: driver={"wiring": whole({...})}
    """An override mapping that replaces the base's mapping instead of merging into it."""


def merged(base: Any, changes: dict[str, Any]) -> dict[str, Any]:
    """``base`` (a mapping, or None) with ``changes`` merged in as the module says."""
    out = dict(base) if isinstance(base, dict) else {}
    for key, value in changes.items():
        if value is DELETE:
            out.pop(key, None)
        elif isinstance(value, whole):
            out[key] = dict(value)
        elif isinstance(value, dict) and isinstance(out.get(key), dict):
            out[key] = merged(out[key], value)
        else:
            out[key] = value
    return out


def _shipped(name: str | Path, folder: Path) -> Path:
    """A shipped file by name (``cell-ur-sim``, ``sorting-gripper.yaml``) or any path."""
    if isinstance(name, Path) or "/" in name:
        return Path(name)
    return folder / (name if name.endswith(".yaml") else f"{name}.yaml")


def _write(tmp_path: Path, stem: str, data: dict) -> Path:
    path = Path(tmp_path) / f"{stem}-{uuid.uuid4().hex[:6]}.yaml"
    path.write_text(yaml.safe_dump(data, sort_keys=False))
    return path


# ---------------------------------------------------------------------- profiles
def profile_data(name: str | Path = "pneunet-gripper", **sections: Any) -> dict[str, Any]:
    return merged(yaml.safe_load(_shipped(name, CONFIG / "profiles").read_text()), sections)


def profile_config(tmp_path: Path, name: str | Path = "pneunet-gripper", *, check: bool = True,
                   **sections: Any) -> Path:
    """A shipped actuator profile with ``sections`` merged in, written next to the test."""
    data = profile_data(name, **sections)
    path = _write(tmp_path, Path(name).stem, data)
    if check:
        validate(Profile, data, path)
    return path


# ---------------------------------------------------------------------- cell configs
def cell_data(tmp_path: Path, base: str | Path | dict = "cell-sim", *, profile: str | Path | dict | None = None,
              **sections: Any) -> dict[str, Any]:
    """The data ``cell_config`` writes. A shipped ``base`` gets the test's own endpoints
    (ipc in ``tmp_path``) and recording directory, and its relative file names made
    absolute (the copy lives elsewhere); a ``base`` path (a config a test or fixture
    wrote) keeps its own, and so does a mapping. ``profile``: a shipped profile's name or
    a path, or overrides merged into the base's profile (then written inline)."""
    from support.harness import ipc_endpoints

    source = CONFIG / "base.yaml" if isinstance(base, dict) else _shipped(base, CONFIG)
    data = copy.deepcopy(base) if isinstance(base, dict) else yaml.safe_load(source.read_text())
    here = source.resolve().parent
    if isinstance(data.get("profile"), str):
        data["profile"] = str(here / data["profile"])
    if isinstance(data.get("gripper"), dict) and data["gripper"].get("calibrations"):
        data["gripper"]["calibrations"] = [str(here / c) for c in data["gripper"]["calibrations"]]
    if not isinstance(base, dict) and source.parent.resolve() == CONFIG.resolve():
        pub, cmd = ipc_endpoints(Path(tmp_path))
        data["publisher"] = merged(data.get("publisher"), {"pub": pub, "cmd": cmd})
        data["recording"] = {"dir": str(Path(tmp_path) / "runs"), "min_free_mb": 16}  # never into the repository
    if isinstance(profile, dict):
        current = data.get("profile")
        data["profile"] = merged(yaml.safe_load(Path(current).read_text()) if isinstance(current, str) else current,
                                 profile)
    elif profile is not None:
        data["profile"] = str(_shipped(profile, CONFIG / "profiles"))
    return merged(data, sections)


def cell_config(tmp_path: Path, base: str | Path | dict = "cell-sim", *, check: bool = True,
                profile: str | Path | dict | None = None, **sections: Any) -> Path:
    """A cell config (``cell_data``) written next to the test; with ``check`` it must
    validate as a CellConfig (files it names need not exist yet: a pty appears later)."""
    data = cell_data(tmp_path, base, profile=profile, **sections)
    path = _write(tmp_path, "cell", data)
    if check:
        named = data.get("profile")
        checked = {**data, "profile": load_profile(named)} if isinstance(named, str) else data
        validate(CellConfig, resolve_calibrations(checked, path), path)
    return path


# ---------------------------------------------------------------------- task files
def task_config(tmp_path: Path, name: str | Path = "sorting", *, check: bool = True, **sections: Any) -> Path:
    """A shipped task file with ``sections`` merged in; its ``cell`` made absolute."""
    source = _shipped(name, CONFIG / "tasks")
    data = yaml.safe_load(source.read_text())
    data["cell"] = str((source.parent / data["cell"]).resolve())
    data = merged(data, sections)
    path = _write(tmp_path, source.stem, data)
    if check:
        validate(TaskDocument, data, path)
    return path


def read(path: Path) -> dict[str, Any]:
    """What a written config holds (to read a value a fixture chose: a host, an endpoint)."""
    return yaml.safe_load(Path(path).read_text())
