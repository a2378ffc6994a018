"""The ``vehsim`` command line (also ``python -m vehsim``).

Subcommands register themselves through `COMMANDS`: each entry is a module with
``register(subparsers)`` that adds a parser whose ``func`` is called with the parsed args.
"""

from __future__ import annotations

import argparse
import importlib
import sys


COMMANDS: tuple[str, ...] = (
    "vehsim.cli",
    "vehsim.sweep",
    "vehsim.identify.cli",
    "vehsim.optimal.cli",
)


def register(subparsers) -> None:
    p = subparsers.add_parser(
        "reproduce", help="regenerate the report's figures and tables into a folder"
    )
    mode = p.add_mutually_exclusive_group()
    mode.add_argument("--quick", dest="quick", action="store_true", default=True,
                      help="small grids and few runs (default, a few minutes on 2 cores)")
    mode.add_argument("--full", dest="quick", action="store_false",
                      help="the report's resolution (slower)")
    p.add_argument("--out", default="results", help="output folder (default: results/)")
    p.add_argument("--only", nargs="*", default=None,
                   help="run only sections whose module name contains one of these words")
    p.set_defaults(func=_reproduce)


def _reproduce(args) -> int:
    from .reproduce import run

    run(args.out, quick=args.quick, only=args.only)
    return 0


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="vehsim", description="Differentiable vehicle simulation (after Tsiotras, 2004)."
    )
    sub = parser.add_subparsers(dest="command", required=True)
    for name in COMMANDS:
        importlib.import_module(name).register(sub)
    return parser


def main(argv: list[str] | None = None) -> int:
    import jax

    jax.config.update("jax_enable_x64", True)
    args = build_parser().parse_args(argv)
    try:
        return int(args.func(args) or 0)
    except (ValueError, FileNotFoundError) as e:
        print(f"vehsim: error: {e}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    raise SystemExit(main())
