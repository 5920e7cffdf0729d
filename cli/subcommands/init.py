"""``fluidsense init``: a starting cell config for a driver, written where the integrator
wants it. It is the shipped example config of that driver (its comments say what to
change for a real cell) with the profile named by its shipped name, so the file works
from any folder (a profile name resolves to the shipped profile unless a file of that
name lies next to the config). The result is loaded like any config before it is
written; an existing file is never replaced without ``--force``."""

from __future__ import annotations

import argparse
import os
import re
import sys
from pathlib import Path

#: driver kind -> the shipped config the starting config is made from
TEMPLATES = {"sim": "cell-sim.yaml", "ur": "cell-ur-sim.yaml", "modbus": "cell-modbus-sim.yaml",
             "serial": "cell-serial-sim.yaml", "nidaqmx": "cell-nidaqmx.yaml"}


def register(sub) -> None:
    p = sub.add_parser(
        "init", help="write a starting cell config for a driver",
        description="Write a starting cell config for a driver: the shipped example config of that driver, its "
        "profile named by its shipped name so that the file works from any folder. Edit the wiring and the host "
        "as its comments say, then `fluidsense check --config FILE`. Refuses to replace an existing file "
        "unless --force.")
    p.add_argument("--driver", "-d", required=True, choices=sorted(TEMPLATES), help="the driver kind")
    p.add_argument("--out", "-o", required=True, help="the file to write, e.g. cell.yaml")
    p.add_argument("--host", help="the control box's address (ur, modbus; default: the emulated box's, 127.0.0.1)")
    p.add_argument("--profile", "-p", help="a shipped profile's name or a profile file (default: the driver "
                   "example's profile)")
    p.add_argument("--force", action="store_true", help="replace an existing file")
    p.set_defaults(func=main)


def starting_config(driver: str, host: str | None = None, profile: str | None = None,
                    out_name: str | None = None) -> str:
    """The text of a starting config for ``driver`` (comments kept; the commands in them
    name ``out_name`` instead of the shipped file)."""
    from fluidsense.common.errors import ConfigError
    from fluidsense.config import SHIPPED

    name = TEMPLATES[driver]
    text = (SHIPPED / name).read_text(encoding="utf-8")
    if out_name is not None:
        text = text.replace(f"config/{name}", out_name)
    shipped = re.search(r"^profile: profiles/([\w.-]+)\.yaml$", text, flags=re.M)
    if shipped is None:  # the shipped file changed shape: a bug here, not the user's input
        raise RuntimeError(f"{name}: no 'profile: profiles/NAME.yaml' line to rewrite")
    text = text[:shipped.start()] + f"profile: {_yaml_scalar(profile or shipped.group(1))}" + text[shipped.end():]
    if host is not None:
        text, n = re.subn(r"^  host: .*$", f"  host: {_yaml_scalar(host)}", text, count=1, flags=re.M)
        if n == 0:
            raise ConfigError(f"--host: the {driver} driver has no host (it is for ur and modbus)")
    return (f"# A starting cell config for the {driver} driver: `fluidsense init --driver {driver}` wrote it from\n"
            f"# the shipped {name}. The profile is named: the file of that name next to this one if there\n"
            "# is one, else the shipped profile (docs/cli.md, \"Files a config names\").\n" + text)


def _yaml_scalar(value: str) -> str:
    """A string as a YAML scalar that reads back as the same string."""
    import json

    return value if re.fullmatch(r"[\w./-]+", value) else json.dumps(value)


def main(args: argparse.Namespace) -> int:
    from fluidsense.common.errors import ConfigError
    from fluidsense.controller.config import load_cell_config

    out = Path(args.out)
    if os.path.lexists(out) and not args.force:
        raise ConfigError(f"--out: {out} exists: pass --force to replace it")
    text = starting_config(args.driver, args.host, args.profile, str(out))
    # loaded from a file beside the target, so that a profile named by a path resolves as
    # it will from the target; only a config that loads is written
    trial = out.with_name(f".{out.name}.init-{os.getpid()}")
    try:
        trial.write_text(text, encoding="utf-8")
        load_cell_config(trial)
        os.replace(trial, out)
    except OSError as exc:  # no such folder, no permission
        raise ConfigError(f"--out: {out}: {exc.strerror or exc}") from exc
    except ConfigError as exc:
        raise ConfigError(str(exc).replace(str(trial), str(out))) from exc
    finally:
        trial.unlink(missing_ok=True)
    print(f"wrote {out}: a {args.driver} cell; edit it as its comments say, then "
          f"`fluidsense check --config {out}`", file=sys.stderr)
    return 0
