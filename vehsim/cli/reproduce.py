"""`vehsim reproduce`: regenerate the report's figures and tables into a folder."""

from __future__ import annotations


def register(subparsers) -> None:
    p = subparsers.add_parser(
        "reproduce", help="regenerate the report's figures and tables into a folder"
    )
    mode = p.add_mutually_exclusive_group()
    mode.add_argument("--quick", dest="quick", action="store_true", default=True,
                      help="small grids and few runs (default, a few minutes on 2 cores)")
    mode.add_argument("--full", dest="quick", action="store_false",
                      help="the report's resolution (slower)")
    mode.add_argument("--tiny", action="store_true",
                      help="the smallest sizes that run every step (for testing the command; "
                           "its numbers are not results)")
    p.add_argument("--out", default="results", help="output folder (default: results/)")
    p.add_argument("--only", nargs="+", action="extend", default=None, metavar="WORD",
                   help="run only sections whose name contains one of these words "
                        "(robot, longitudinal, identify, combined, vehicle, optimal, "
                        "braking_control)")
    p.set_defaults(func=_reproduce)


def _reproduce(args) -> int:
    from ..reproduce import run

    if args.only is not None and not all(w.strip() for w in args.only):
        raise ValueError("--only: an empty word (it would match every section)")
    run(args.out, quick=args.quick, only=args.only, tiny=args.tiny)
    return 0
