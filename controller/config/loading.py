"""Reading configuration files: YAML in, validated models out, every problem one line
``FILE: field.path: reason`` (``FILE:LINE:COLUMN: ...`` when the problem has a place in
the file) raised as one ConfigError.

The files are untrusted: drivers/files.py opens them (regular files only, a size cap),
controller/yamlfile.py builds the document (depth, aliases, duplicate keys, non-finite
numbers, NUL), and the models check types (strict numbers), ranges and consistency.
"""

from __future__ import annotations

import os
import stat
from pathlib import Path
from typing import Any, TypeVar

import yaml
from fluidsense.common.errors import ConfigError
from fluidsense.common.files import (
    YAML_MAX_BYTES,
    check_name,
    decode_utf8,
    describe,
    one_line,
    read_bounded,
)
from fluidsense.common.models import FieldError
from fluidsense.config import SHIPPED
from fluidsense.controller.config import yamlfile
from pydantic import BaseModel, ValidationError

M = TypeVar("M", bound=BaseModel)


def _field_path(loc: tuple, data: Any) -> str:
    """Dotted field path of an error location, without the union tags pydantic inserts
    (``driver.sim.rate_hz`` -> ``driver.rate_hz``): the path the user wrote."""
    parts, node = [], data
    for item in loc:
        if isinstance(node, dict) and item not in node and item in (node.get("kind"), node.get("task")):
            continue  # the tag of a discriminated union, not a key in the file
        if isinstance(item, str) and item.startswith("function-"):
            continue
        parts.append(str(item))
        if isinstance(node, dict):
            node = node.get(item)
        elif isinstance(node, list) and isinstance(item, int) and 0 <= item < len(node):
            node = node[item]
        else:
            node = None
    return ".".join(parts)


def format_errors(path: str | Path, exc: ValidationError, data: Any, prefix: str = "") -> str:
    lines = []
    for err in exc.errors():
        loc = _field_path(err["loc"], data)
        msg = err["msg"].removeprefix("Value error, ")
        cause = (err.get("ctx") or {}).get("error")
        if isinstance(cause, FieldError):  # a model's check about one of its fields
            loc, msg = f"{loc}.{cause.field}" if loc else cause.field, cause.reason
        loc = f"{prefix}{loc}" if loc else (prefix.rstrip(".") or "(top level)")
        if err["type"] == "extra_forbidden":
            msg = "unknown field (not allowed here)"
        elif err["type"] == "missing":
            msg = "required field is missing"
        lines.append(f"{path}: {one_line(loc)}: {one_line(msg)}")
    return "\n".join(lines)


def read_yaml(path: str | Path) -> Any:
    """The document in a YAML file (None for an empty one)."""
    path = check_name(path)
    text = decode_utf8(read_bounded(path, YAML_MAX_BYTES, "a YAML file"), path)
    try:
        return yamlfile.parse(text)
    except yamlfile.YamlRefused as exc:
        raise ConfigError(f"{path}:{exc.mark.line + 1}:{exc.mark.column + 1}: {one_line(exc.field)}: "
                          f"{one_line(exc.reason)}") from exc
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        where = f":{mark.line + 1}:{mark.column + 1}" if mark else ""
        reason = getattr(exc, "problem", None) or str(exc)
        raise ConfigError(f"{path}{where}: YAML syntax: {one_line(reason)}") from exc
    except ValueError as exc:  # an explicitly tagged value that cannot be built: !!int abc
        raise ConfigError(f"{path}: YAML value: {one_line(str(exc))}") from exc


def validate(model: type[M], data: Any, path: str | Path, prefix: str = "") -> M:
    """Validate ``data`` read from ``path``; errors become ConfigError naming file and field."""
    where = prefix.rstrip(".") or "(top level)"
    if data is None and not prefix:
        raise ConfigError(f"{path}: {where}: the file is empty")
    if not isinstance(data, dict):
        raise ConfigError(f"{path}: {where}: expected a mapping, got {type(data).__name__}")
    try:
        return model.model_validate(data)
    except ValidationError as exc:
        raise ConfigError(format_errors(path, exc, data, prefix)) from exc
    except RecursionError as exc:  # a structure the YAML loader would have refused, built in code
        raise ConfigError(f"{path}: {where}: nested too deeply") from exc


def load_model(model: type[M], path: str | Path) -> M:
    return validate(model, read_yaml(path), path)


def referenced_file(path: str | Path, by: str | Path, field: str) -> Path:
    """A file named by a field of another file must be a regular file that exists: the
    error names the file and field that name it."""
    text = os.fspath(path)
    if "\0" in text:
        raise ConfigError(f"{by}: {field}: the file name contains a NUL byte")
    try:
        st = os.stat(text)
    except OSError as exc:
        raise ConfigError(f"{by}: {field}: {one_line(text)}: {exc.strerror or exc}") from exc
    if not stat.S_ISREG(st.st_mode):
        raise ConfigError(f"{by}: {field}: {one_line(text)} is not a regular file ({describe(st.st_mode)})")
    return Path(text)


def _missing(text: str) -> bool:
    try:
        os.stat(text)
    except FileNotFoundError:
        return True
    except (OSError, ValueError):
        return False  # there, or a name that cannot be: referenced_file says which
    return False


def shipped_candidates(name: str, folder: str, suffix: str) -> list[Path]:
    """Where a shipped ``folder`` (profiles, calibrations) file named ``name`` would be:
    ``NAME``, ``NAME`` + ``suffix`` in it, or ``folder/NAME`` as a copy of a shipped config
    names it. Only plain names: nothing that climbs out of the shipped folder."""
    parts = Path(name).parts
    if not parts or Path(name).is_absolute() or ".." in parts or "\0" in name:
        return []
    if len(parts) == 2 and parts[0] == folder:
        parts = parts[1:]
    if len(parts) != 1:
        return []
    base = SHIPPED / folder / parts[0]
    return [base] if parts[0].endswith(suffix) else [base.with_name(parts[0] + suffix), base]


def named_file(name: str, by: str | Path, field: str, folder: str, suffix: str) -> Path:
    """A profile or calibration named by a cell config. The resolution order: (1) the name
    as a path, absolute or relative to the folder of the file ``by`` that names it; (2)
    when no such file exists, the shipped one of that name (``pneunet-gripper``,
    ``pneunet-gripper.yaml`` or ``profiles/pneunet-gripper.yaml``), so that a copy of a
    shipped config works from anywhere. The error names both places looked at."""
    local = Path(by).parent / name
    text = os.fspath(local)
    if "\0" in text or not _missing(text):
        return referenced_file(local, by, field)
    candidates = shipped_candidates(name, folder, suffix)
    if not candidates:  # a path of the user's own: only it was looked at
        return referenced_file(local, by, field)
    for candidate in candidates:
        if not _missing(os.fspath(candidate)):
            return referenced_file(candidate, by, field)
    known = ", ".join(sorted(p.name.removesuffix(suffix) for p in (SHIPPED / folder).glob(f"*{suffix}")))
    raise ConfigError(f"{by}: {field}: {one_line(text)}: No such file or directory, and no shipped file of "
                      f"that name in {folder}/ (shipped: {known})")


__all__ = ["format_errors", "load_model", "named_file", "one_line", "read_yaml", "referenced_file", "validate"]
