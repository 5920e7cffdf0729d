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
        description="With the gripper empty, run free-air cycles of the tank circuit at several P0 levels (or of the "
        "pressure-flow circuit at several regulated pressures, the flow into the actuator integrated) and fit "
        "what the rig can show: the actuator's free volume and compliance (eq. 1; scaled by the tank and hose the "
        "config states; with the flow sensor, in absolute volume), the lag, the settling time, the leak, the "
        "cycle-to-cycle spread and the sensor's noise; "
        "for a laminar circuit without a hose also the path's resistance. With --targets, then cycles at the "
        "profile's P0 on each of two or three objects of known size (placed as calibrate asks for them) fit the "
        "contact law the simulator needs (a gripper's opening, closing per ml and wrap ratio). Writes a profile "
        "whose every fitted number carries its 95 %% interval and provenance; the rest is the starting profile's "
        "(said so per field). Refuses to write a fit that does not hold. Finished cycles are kept in "
        "OUT.cycles.jsonl and OUT.contact.jsonl (--resume).")
    p.add_argument("--config", "-c", required=True, help="cell config (its driver reaches the rig)")
    p.add_argument("--out", "-o", required=True, help="the profile to write (YAML)")
    p.add_argument("--from", dest="start", metavar="PROFILE", help="starting profile, file or shipped name "
                   "(default: the config's): its sequence runs the cycles and its values stay where the rig "
                   "cannot show them")
    p.add_argument("--levels", help="comma-separated P0 levels in kPa (default: 5 from 20 %% of the starting "
                   "profile's P0 up to it; a pressure-flow circuit's top stays where the opening's flow is within "
                   "90 %% of the flow sensor's range)")
    p.add_argument("--cycles", type=int, default=4, help="cycles per level (default 4, at least 2)")
    p.add_argument("--name", help="the written profile's name (default: the starting one's + '-characterised')")
    p.add_argument("--seed", type=int, default=1, help="seed of a simulated cell (default 1)")
    p.add_argument("--targets", metavar="SIZES", help="comma-separated sizes of two or three rigid objects, in "
                   "the scene's unit (a gripper's cylinders: diameter in mm, e.g. 60,100): after the free-air "
                   "cycles, cycles at P0 on each fit the contact law (default: none, the contact law is kept)")
    p.add_argument("--target-cycles", type=int, help="cycles per target, and in free air before them (default: "
                   "--cycles)")
    p.add_argument("--targets-from", metavar="FILE", help="real cell, scripted: read one line per placed target "
                   "(its size) from FILE, e.g. a FIFO another program writes, instead of asking at the terminal")
    p.add_argument("--yes", action="store_true", help="do not ask whether the gripper is empty; on a real cell "
                   "with --targets and without --targets-from, do not wait for the targets either (placed in the "
                   "listed order by other means)")
    p.add_argument("--resume", action="store_true", help="continue a run that stopped: the cycles in "
                   "OUT.cycles.jsonl and OUT.contact.jsonl are not run again")
    p.add_argument("--json", action="store_true", help="print the result as JSON")
    p.set_defaults(func=cmd_characterise)


def _levels(text: str, option: str = "--levels", unit: str = "kPa") -> list[float]:
    try:
        return [float(v) for v in text.split(",") if v.strip()]
    except ValueError as exc:
        raise ConfigError(f"{option} {text!r}: give comma-separated numbers in {unit}") from exc


def contact_path(out: Path) -> Path:
    """Where the contact step's cycles are kept, beside the profile."""
    return Path(f"{out}.contact.jsonl")


def _can_ask_empty(yes: bool, needs_operator: bool) -> None:
    """Before anything is opened: the question below can be asked."""
    if not yes and needs_operator and not sys.stdin.isatty():
        raise CommandError("characterise asks that the gripper be empty before any valve moves, and stdin is not a "
                           "terminal: run it in one, or pass --yes once the gripper is empty")


def _ask_empty(yes: bool, needs_operator: bool) -> None:
    """Before any valve moves: the gripper must hold nothing (its free-air law is measured)."""
    _can_ask_empty(yes, needs_operator)
    if yes or not needs_operator:
        return
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

    targets, spec, tcycles = None, None, args.target_cycles or args.cycles
    if args.targets:
        from fluidsense.tasks import contact as ct

        if ch.is_flow(start):
            raise ConfigError("--targets: the contact step reads the tank circuit's equilibria; with the "
                              "pressure-flow circuit it is not built yet (the free-air law alone is characterised)")
        spec = ct.spec_of(start)
        targets = ct.check_plan(start, _levels(args.targets, "--targets", spec.unit), tcycles)
    elif args.target_cycles is not None or args.targets_from is not None:
        raise ConfigError("--target-cycles and --targets-from go with --targets")
    real = cfg.driver.needs_operator()
    operator = None
    if targets is not None and real:  # before anything is opened or moves: who places the targets
        from .calibrate import Operator

        operator = Operator(spec.target, args.targets_from, args.yes and args.targets_from is None,
                            job="characterising")
    try:
        _can_ask_empty(args.yes, real)
        plan = {"profile": start.name, "levels_kpa": levels, "cycles": args.cycles,
                "sequence": start.sequence.model_dump(mode="json"), "config": str(Path(args.config).resolve())}
        journal = ch.CharacteriseJournal.open(journal_path(out), plan, resume=args.resume)
        cjournal = None
        if targets is not None:
            cplan = {**plan, "scene": spec.scene, "target": spec.target, "values": targets, "cycles": tcycles,
                     "p0_kpa": start.sequence.p0_kpa, "grid_kpa": ct.grid_kpa(start)}
            cpath = contact_path(out)
            cjournal = ct.ContactJournal.open(cpath, cplan, resume=args.resume and cpath.exists())
        _ask_empty(args.yes, real)
    except BaseException:
        if operator is not None:
            operator.close()
        raise
    total = len(levels) * args.cycles + (0 if targets is None else (len(targets) + 1) * tcycles)
    done = len(journal.entries) + (len(cjournal.entries) if cjournal is not None else 0)
    if done:
        print(f"resuming: {done} of {total} cycles done ({journal.path}"
              + (f", {cjournal.path}" if cjournal is not None else "") + ")", file=sys.stderr)
        if cfg.driver.samples_seed() is not None:
            # a simulated cell started again with the same seed draws what the cycles already
            # done drew: the resumed cycles would repeat them exactly and show no spread (the
            # fit refused a resumed run so). A real cell does not repeat itself.
            cfg = cfg.model_copy(update={"driver": cfg.driver.for_job(args.seed + done)})
    valves = []

    async def nobody_places(_scene) -> None:
        """A real cell's gripper stays empty from the question above to the first target."""

    async def job():
        async with app.controller(cfg, own_process=True) as ctrl:
            valves.append(ctrl.backend.valves)
            port = ctrl.task_port
            place_free = nobody_places if real else port.place
            with tqdm(total=total, initial=done, desc=f"characterising {start.name}", unit="cycle",
                      file=sys.stderr, disable=args.json) as bar:
                entries = await ch.measure(port, levels, args.cycles, journal, place=place_free,
                                           progress=bar.update)
                if targets is None:
                    return entries, None
                bar.set_description(f"characterising {start.name}: targets")
                if operator is not None:
                    operator.bar = bar
                contact_entries = await ct.measure(port, targets, tcycles, cjournal,
                                                   place=operator.place if operator else port.place,
                                                   place_free=place_free, progress=bar.update)
                return entries, contact_entries

    kept_words = f"{journal.path}" + (f" and {cjournal.path}" if cjournal is not None else "")
    try:
        entries, contact_entries = stopsignals.run(job())
    except JobStopped as exc:
        print_stopped(exc, args.json)
        return EXIT_FAULT
    except KeyboardInterrupt as exc:  # Ctrl-C, SIGTERM, SIGHUP: after the controller vented
        now = len(journal.entries) + (len(cjournal.entries) if cjournal is not None else 0)
        return print_signal_stop(stopsignals.interruption(exc), "characterisation", valves[0] if valves else None,
                                 f"{now} of {total} cycles are kept in {kept_words}: run again with --resume")
    finally:
        if operator is not None:
            operator.close()
    try:
        result = ch.fit(entries, start)
    except ch.FitRefused as exc:
        print(f"fluidsense: {exc}; no profile written (the cycles are kept in {kept_words})", file=sys.stderr)
        if args.json:
            print(json.dumps({"refused": exc.reasons, "journal": str(journal.path),
                              **(exc.result.to_dict() if exc.result else {})}, indent=2))
        return EXIT_REFUSED
    contact = check = None
    if targets is not None:
        import numpy as np

        try:
            contact = ct.fit(contact_entries, start, result.value("actuator.v0_ml"),
                             result.value("actuator.compliance_ml_per_kpa"), np.array(result.pv_cov))
        except ct.ContactRefused as exc:
            return _contact_refused(exc.reasons, exc.result, kept_words, args.json)
    rig = _rig_words(cfg.driver)
    date = datetime.datetime.now(datetime.UTC)
    common = dict(name=name, rig=rig, config=str(Path(args.config).resolve()),
                  from_profile=f"{start.name} ({Path(start_path).resolve()})", levels=levels, cycles=args.cycles,
                  cycle_ids=[e["cycle_id"] for e in entries], date=date)
    data = ch.characterised_profile(start_data, start, result, **common, contact=contact)
    if contact is not None:
        # the check: the written profile's simulated cell at the same targets (virtual time)
        from fluidsense.controller.config.profile import Profile
        from fluidsense.controller.service import open_cell

        mine = Profile.model_validate(data)
        try:
            sim_entries = stopsignals.run(ct.simulate(mine, targets, tcycles, seed=args.seed + 7919,
                                                      open_cell=open_cell))
        except KeyboardInterrupt as exc:  # the rig's valves were vented when its cycles ended
            sig = stopsignals.interruption(exc)
            print(f"fluidsense: characterisation stopped by {sig.name} during the simulated check (the rig's cycles "
                  f"had ended and vented); no profile written; the cycles are kept in {kept_words}: run again with "
                  "--resume", file=sys.stderr, flush=True)
            return sig.exit_code
        try:
            check = ct.compare(contact, sim_entries, mine,
                               timing_fitted=result.value("circuit.valve_delay_s") is not None)
        except ct.ContactRefused as exc:  # the simulated cell read no spread: cannot happen with its noise
            return _contact_refused([f"the simulated check: {r}" for r in exc.reasons], contact, kept_words,
                                    args.json)
        if not check.ok:
            return _contact_refused([f"the simulated cell of the fitted profile does not reproduce the rig's "
                                     f"{', '.join(check.disagree)} (" + "; ".join(check.lines[1:]) + ")"],
                                    contact, kept_words, args.json)
        data = ch.characterised_profile(start_data, start, result, **common, contact=contact,
                                        contact_block=ct.provenance(contact, mine, tcycles, check))
    _write(out, data, ch.profile_comments(result, f"{rig}, {date.isoformat(timespec='seconds')}, config "
                                                  f"{args.config}, {len(levels)} levels x {args.cycles} cycles"
                                          + ("" if targets is None else
                                             f", targets {','.join(f'{v:g}' for v in targets)} {spec.unit} x "
                                             f"{tcycles} cycles"), contact))
    if args.json:
        print(json.dumps({"profile": str(out), "journal": str(journal.path), **result.to_dict(),
                          **({} if contact is None else {"contact_journal": str(cjournal.path),
                                                         "contact": {**contact.to_dict(), "check": check.lines}})},
                         indent=2))
        return EXIT_OK
    for f in result.fitted + (contact.fitted if contact is not None else []):
        print(f"{f.field} = {f.value:.5g} {f.unit}  (95 % {f.lo95:.5g} .. {f.hi95:.5g})")
    if result.residual_ml is not None:
        print(f"P-V fit (V_eq against Pe): residual {result.residual_ml:.3g} ml rms over {len(levels)} levels; the "
              f"cycles' own spread {result.pure_error_ml:.3g} ml")
    else:
        print(f"P-V fit: residual {result.residual_kpa:.3g} kPa rms over {len(levels)} levels; the cycles' own "
              f"spread {result.pure_error_kpa:.3g} kPa")
    if contact is not None:
        for note in contact.notes:
            print(note)
        print("the written profile's simulated cell against the rig:")
        for line in check.lines:
            print(f"  {line}")
    kept = dict(result.kept) if contact is None else {**result.kept, **contact.kept}
    print(f"saved {out} (cycles in {kept_words}; kept from {start.name}: {', '.join(kept)})")
    return EXIT_OK


def _contact_refused(reasons: list[str], result, kept_words: str, as_json: bool) -> int:
    print("fluidsense: contact fit refused: " + "; ".join(reasons) + f"; no profile written (the cycles are kept "
          f"in {kept_words}; without --targets the free-air profile alone is written from them with --resume)",
          file=sys.stderr)
    if as_json:
        print(json.dumps({"refused": reasons, **({"contact": result.to_dict()} if result is not None else {})},
                         indent=2))
    return EXIT_REFUSED


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
