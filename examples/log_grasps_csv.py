"""Log every grasp (and slip) of a running daemon to a CSV file, one row per event.

    python examples/log_grasps_csv.py --pub tcp://127.0.0.1:5560 --cmd tcp://127.0.0.1:5561 grasps.csv

Runs until Ctrl-C, or ``--count`` rows, or ``--idle S`` seconds without an event.
"""

from __future__ import annotations

import argparse
import csv
import sys

from fluidsense.client import Grasp, Gripper, Slip

FIELDS = ["utc_s", "t_s", "topic", "cycle_id", "object", "quantity", "value_mm", "lo_mm", "hi_mm", "status",
          "p_eq_kpa", "drop_kpa"]


def row(ev) -> dict:
    base = {"utc_s": ev.event.utc_s, "t_s": ev.event.t_s, "topic": ev.event.topic, "cycle_id": ev.cycle_id,
            "object": ev.object}
    est = ev.estimates[0] if ev.estimates else None
    if est is not None:
        base.update(quantity=est.quantity, value_mm=est.value_mm, lo_mm=est.lo_mm, hi_mm=est.hi_mm, status=est.status)
    if isinstance(ev, Grasp):
        base["p_eq_kpa"] = ev.features.get("p_eq_kpa")
    else:
        base["drop_kpa"] = ev.drop_kpa
    return base


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("out")
    p.add_argument("--pub", default="tcp://127.0.0.1:5560")
    p.add_argument("--cmd", default="tcp://127.0.0.1:5561")
    p.add_argument("--count", type=int, help="stop after this many rows")
    p.add_argument("--idle", type=float, help="stop after this many seconds without an event")
    args = p.parse_args(argv)
    n = 0
    with Gripper(args.cmd, args.pub, topics=("grasp", "slip")) as g, open(args.out, "w", newline="") as f:
        g.attach(30)
        writer = csv.DictWriter(f, FIELDS)
        writer.writeheader()
        f.flush()
        try:
            for ev in g.events(timeout_s=args.idle):
                if isinstance(ev, (Grasp, Slip)):
                    writer.writerow(row(ev))
                    f.flush()
                    n += 1
                    if args.count is not None and n >= args.count:
                        break
        except KeyboardInterrupt:
            pass
    print(f"{n} rows in {args.out}", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
