"""``fluidsense characterise``: free-air cycles over a sweep of P0, and the profile they give."""

from __future__ import annotations

import argparse
import datetime
import json
import os
import sys
from pathlib import Path

from fluidsense.common import stopsignals
from fluidsense.common.errors import CommandError, ConfigError, JobStopped
from fluidsense.common.exitcodes import EXIT_FAILURE, EXIT_FAULT, EXIT_OK

from ._common import print_signal_stop, print_stopped, setup_logging

EXIT_REFUSED = EXIT_FAILURE  # the cycles ran, the fit does not hold: no profile written (as replay's mismatch)


def register(sub) -> None:
    p = sub.add_parser(
        "characterise", help="measure your actuator's free P-V law and the rig's timing and noise; write a profile",
        description="With the gripper empty, run free-air cycles of the tank circuit at several P0 levels and fit "
        "what the rig can show: the actuator's free volume and compliance (eq. 1; scaled by the tank and hose the "
        "config states), the lag, the settling time, the leak, the cycle-to-cycle spread and the sensor's noise; "
        "for a laminar circuit without a hose also the path's resistance. Writes a profile whose every fitted "
        "number carries its 95 %% interval and provenance; the rest is the starting profile's (said so per field). "
        "Refuses to write a fit that does not hold. Finished cycles are kept in OUT.cycles.jsonl (--resume).")
    p.add_argument("--config", "-c", required=True, help="cell config (its driver reaches the rig)")
    p.add_argument("--out", "-o", required=True, help="the profile to write (YAML)")
    p.add_argument("--from", dest="start", metavar="PROFILE", help="starting profile, file or shipped name "
                   "(default: the config's): its sequence runs the cycles and its values stay where the rig "
                   "cannot show them")
    p.add_argument("--levels", help="comma-separated P0 levels in kPa (default: 5 from 40 %% of the starting "
                   "profile's P0 up to it)")
    p.add_argument("--cycles", type=int, default=4, help="cycles per level (default 4, at least 2)")
    p.add_argument("--name", help="the written profile's name (default: the starting one's + '-characterised')")
    p.add_argument("--seed", type=int, default=1, help="seed of a simulated cell (default 1)")
    p.add_argument("--yes", action="store_true", help="do not ask whether the gripper is empty (scripts)")
    p.add_argument("--resume", action="store_true", help="continue a run that stopped: the cycles in "
                   "OUT.cycles.jsonl are not run again")
    p.add_argument("--json", action="store_true", help="print the result as JSON")
    p.set_defaults(func=cmd_characterise)


def _levels(text: str) -> list[float]:
    try:
        return [float(v) for v in text.split(",") if v.strip()]
    except ValueError as exc:
        raise ConfigError(f"--levels {text!r}: give comma-separated numbers in kPa") from exc


def _ask_empty(yes: bool, needs_operator: bool) -> None:
    """Before any valve moves: the gripper must hold nothing (its free-air law is measured)."""
    if yes or not needs_operator:
        return
    if not sys.stdin.isatty():
        raise CommandError("characterise asks that the gripper be empty before any valve moves, and stdin is not a "
                           "terminal: run it in one, or pass --yes once the gripper is empty")
    print(">>> clear the actuator: nothing may touch it while it inflates in free air; press Enter when it is "
          "clear (Ctrl-C to stop)", file=sys.stderr, flush=True)
    if not sys.stdin.readline():
        raise CommandError("stdin closed while waiting for the operator")


def cmd_characterise(args: argparse.Namespace) -> int:
    from fluidsense.controller.config import load_cell_config, load_profile
    from fluidsense.controller.config.loading import read_yaml
    from fluidsense.daemon import app
    from fluidsense.tasks import characterise as ch
    from tqdm import tqdm

    from ..options import profile_path

    cfg = load_cell_config(args.config)
    cfg = cfg.model_copy(update={"driver": cfg.driver.for_job(args.seed)})
    if args.start:
        start_path = profile_path(args.start)
        start = load_profile(start_path)
        cfg = cfg.model_copy(update={"profile": start})
    else:
        start, start_path = cfg.profile, _config_profile_path(args.config)
    setup_logging(cfg.log_level, quiet=True)
    levels = ch.check_plan(start, _levels(args.levels) if args.levels else ch.default_levels(start), args.cycles)
    start_data = read_yaml(start_path)
    out = Path(args.out)
    if out.suffix not in (".yaml", ".yml"):
        raise ConfigError(f"--out {args.out}: a profile is a .yaml file")
    if out.exists():
        raise ConfigError(f"--out {args.out}: exists; move it away (a profile is never overwritten)")
    name = args.name or f"{start.name}-characterised"[:80]
    from fluidsense.tasks.journal import journal_path

    plan = {"profile": start.name, "levels_kpa": levels, "cycles": args.cycles,
            "sequence": start.sequence.model_dump(mode="json"), "config": str(Path(args.config).resolve())}
    journal = ch.CharacteriseJournal.open(journal_path(out), plan, resume=args.resume)
    total = len(levels) * args.cycles
    if journal.entries:
        print(f"resuming: {len(journal.entries)} of {total} cycles done ({journal.path})", file=sys.stderr)
        if cfg.driver.samples_seed() is not None:
            # a simulated cell started again with the same seed draws what the cycles already
            # done drew: the resumed cycles would repeat them exactly and show no spread (the
            # fit refused a resumed run so). A real cell does not repeat itself.
            cfg = cfg.model_copy(update={"driver": cfg.driver.for_job(args.seed + len(journal.entries))})
    _ask_empty(args.yes, cfg.driver.needs_operator())
    valves = []

    async def job():
        async with app.controller(cfg, own_process=True) as ctrl:
            valves.append(ctrl.backend.valves)
            with tqdm(total=total, initial=len(journal.entries), desc=f"characterising {start.name}",
                      unit="cycle", file=sys.stderr, disable=args.json) as bar:
                return await ch.measure(ctrl.task_port, levels, args.cycles, journal, progress=bar.update)

    try:
        entries = stopsignals.run(job())
    except JobStopped as exc:
        print_stopped(exc, args.json)
        return EXIT_FAULT
    except KeyboardInterrupt as exc:  # Ctrl-C, SIGTERM, SIGHUP: after the controller vented
        return print_signal_stop(stopsignals.interruption(exc), "characterisation", valves[0] if valves else None,
                                 f"{len(journal.entries)} of {total} cycles are kept in {journal.path}: run again "
                                 "with --resume")
    try:
        result = ch.fit(entries, start)
    except ch.FitRefused as exc:
        print(f"fluidsense: {exc}; no profile written (the cycles are kept in {journal.path})", file=sys.stderr)
        if args.json:
            print(json.dumps({"refused": exc.reasons, "journal": str(journal.path),
                              **(exc.result.to_dict() if exc.result else {})}, indent=2))
        return EXIT_REFUSED
    rig = _rig_words(cfg.driver)
    date = datetime.datetime.now(datetime.UTC)
    data = ch.characterised_profile(start_data, start, result, name=name, rig=rig,
                                    config=str(Path(args.config).resolve()),
                                    from_profile=f"{start.name} ({Path(start_path).resolve()})", levels=levels,
                                    cycles=args.cycles, cycle_ids=[e["cycle_id"] for e in entries], date=date)
    _write(out, data, ch.profile_comments(result, f"{rig}, {date.isoformat(timespec='seconds')}, config "
                                                  f"{args.config}, {len(levels)} levels x {args.cycles} cycles"))
    if args.json:
        print(json.dumps({"profile": str(out), "journal": str(journal.path), **result.to_dict()}, indent=2))
        return EXIT_OK
    for f in result.fitted:
        print(f"{f.field} = {f.value:.5g} {f.unit}  (95 % {f.lo95:.5g} .. {f.hi95:.5g})")
    print(f"P-V fit: residual {result.residual_kpa:.3g} kPa rms over {len(levels)} levels; the cycles' own spread "
          f"{result.pure_error_kpa:.3g} kPa")
    print(f"saved {out} (cycles in {journal.path}; kept from {start.name}: {', '.join(result.kept)})")
    return EXIT_OK


def _config_profile_path(config: str) -> Path:
    """The profile file a cell config names (as the loader resolves it)."""
    from fluidsense.controller.config.loading import named_file, read_yaml

    data = read_yaml(config)
    ref = data.get("profile") if isinstance(data, dict) else None
    if not isinstance(ref, str):
        raise ConfigError(f"{config}: profile: characterise needs the profile as a file name (or give --from)")
    return named_file(ref, config, "profile", "profiles", ".yaml")


def _rig_words(driver) -> str:
    where, seed = getattr(driver, "host", None), driver.samples_seed()
    return f"driver {driver.kind}" + (f" at {where}" if where else "") + (
        f" (simulated, seed {seed})" if seed is not None else "")


def _write(path: Path, data: dict, header: str) -> None:
    import yaml

    tmp = path.with_name(path.name + ".tmp")
    tmp.write_text(header + yaml.safe_dump(data, sort_keys=False, allow_unicode=True), encoding="utf-8")
    os.replace(tmp, path)
