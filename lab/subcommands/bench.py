"""``python -m lab bench NAME``: benchmarks that print figures (see lab/bench/)."""

from __future__ import annotations


def register(sub, full: bool = True) -> None:
    """``full``: find the benches and their options (imports every bench module, numpy
    and more); only when the command line asks for a bench, so that every other command,
    and ``fluidsense --help``, starts quickly."""
    p = sub.add_parser("bench", help="benchmarks (print figures; --json for machines)",
                       description="Run a benchmark. Speed and memory goals live here, not in the tests.")
    if not full:
        return
    from ..bench import discover

    benches = p.add_subparsers(dest="bench", required=True, metavar="NAME")
    for name, module in discover().items():
        # argparse %-formats a help string: "95 % error" would end the listing in a ValueError
        bp = benches.add_parser(name, help=module.HELP.replace("%", "%%"),
                                description=getattr(module, "DESCRIPTION", module.HELP))
        module.register(bp)
        bp.set_defaults(func=module.run)
