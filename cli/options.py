"""Command-line options shared by the jobs: which cell, which scene."""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any

# kept light: the parsers of every command are built from these, and `fluidsense --help`
# must not wait for pydantic, numpy or the configs (imported where they are used)
PROFILES = Path(__file__).resolve().parent.parent / "config" / "profiles"


def add_cell_options(p: argparse.ArgumentParser) -> None:
    g = p.add_mutually_exclusive_group()
    g.add_argument("--config", "-c", help="cell config YAML (default: a simulated cell for --profile)")
    g.add_argument("--profile", "-p", help="actuator profile YAML, or a name: shipped (config/profiles/) or "
                   "NAME.yaml here (runs on a simulated cell in virtual time)")
    p.add_argument("--seed", type=int, default=1, help="seed of the simulated cell (default 1)")


def add_scene_options(p: argparse.ArgumentParser) -> None:
    p.add_argument("--scene", help="simulated scene kind, e.g. plate, cylinder, sample, stopper")
    p.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                   help="scene field, repeatable, e.g. --set height_mm=17.5")


def _exists(path: Path) -> bool:
    try:
        return path.exists()
    except (OSError, ValueError):  # a name too long; a NUL (the name may come from a calibration file)
        return False


def profile_path(name: str) -> Path:
    """A profile by its file, or by its name: a shipped one (``pneunet-gripper``), or one of
    your own in the working directory (``mine`` for mine.yaml, as ``fluidsense characterise
    --out mine.yaml`` writes it). A name that is both is refused: give the file."""
    from fluidsense.common.errors import ConfigError
    from fluidsense.common.files import one_line

    if _exists(Path(name)):
        return Path(name)
    shipped = next((c for c in (PROFILES / name, PROFILES / f"{name}.yaml") if _exists(c)), None)
    own = next((c for c in (Path(f"{name}.yaml"), Path(f"{name}.yml")) if _exists(c)), None)
    if shipped is not None and own is not None:
        raise ConfigError(f"{one_line(name)}: both {own} here and the shipped profile of that name: give the file "
                          f"(./{own}) or rename yours")
    if shipped is not None or own is not None:
        return shipped or own
    known = ", ".join(sorted(p.stem for p in PROFILES.glob("*.yaml")))
    raise ConfigError(f"{one_line(name)}: no such profile file, no {one_line(name)}.yaml here and no shipped profile "
                      f"of that name (shipped: {known})")


def cell_config(args: argparse.Namespace, default_profile: str | None = None):
    """The cell for a job. Simulated cells run in virtual time with ``--seed``."""
    from fluidsense.common.errors import ConfigError
    from fluidsense.controller.config import CellConfig, load_cell_config, load_profile
    from fluidsense.drivers.registry import SimDriverConfig

    if args.config:
        cfg = load_cell_config(args.config)
        return cfg.model_copy(update={"driver": cfg.driver.for_job(args.seed)})
    name = args.profile or default_profile
    if name is None:
        raise ConfigError("give --profile NAME (a file in config/profiles/) or --config CELL.yaml")
    profile = load_profile(profile_path(name))
    return CellConfig(driver=SimDriverConfig(clock="virtual", seed=args.seed), profile=profile)


def _value(text: str) -> Any:
    for cast in (int, float):
        try:
            return cast(text)
        except ValueError:
            pass
    if text.lower() in ("none", "null"):
        return None
    return text


def apply_sets(data: dict[str, Any], sets: list[str]) -> None:
    """``--set KEY=VALUE`` items into ``data`` (values read as numbers where they are)."""
    from fluidsense.common.errors import ConfigError

    for item in sets:
        key, sep, value = item.partition("=")
        if not sep or not key:
            raise ConfigError(f"--set {item!r}: expected KEY=VALUE")
        data[key.strip()] = _value(value.strip())


def floats(text: str, name: str) -> list[float]:
    """A comma-separated list of numbers given to option ``name``."""
    from fluidsense.common.errors import ConfigError

    try:
        return [float(v) for v in text.split(",") if v.strip()]
    except ValueError:
        raise ConfigError(f"{name}: expected comma-separated numbers, got {text!r}") from None


def scene_from_args(args: argparse.Namespace, base: Any | None = None) -> Any | None:
    """``--scene NAME --set k=v ...`` on top of ``base`` (a scene or None)."""
    from fluidsense.common.errors import ConfigError
    from fluidsense.common.models import first_error
    from fluidsense.common.scenes import Scene
    from pydantic import TypeAdapter, ValidationError

    if args.scene is None and not args.set:
        return base
    data: dict[str, Any] = base.model_dump() if base is not None else {}
    if args.scene is not None:
        if data.get("kind") != args.scene:
            data = {}
        data["kind"] = args.scene
    apply_sets(data, args.set)
    try:
        return TypeAdapter(Scene).validate_python(data)
    except ValidationError as exc:
        raise ConfigError(f"--scene/--set: {first_error(exc, 'scene', skip=1)}") from None
