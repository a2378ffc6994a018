"""The ``vehsim`` command line (also ``python -m vehsim``).

One module per subcommand (`reproduce`, `sweep`, `fit`, `optimise`, `brake`), each with
``register(subparsers)`` adding a parser whose ``func`` is called with the parsed arguments.
A `ValueError` or a missing file ends the command with exit status 2 and the message.
"""

from __future__ import annotations

import argparse
import sys

from . import brake, fit, optimise, reproduce, sweep


COMMANDS = (reproduce, sweep, fit, optimise, brake)


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="vehsim", description="Differentiable vehicle simulation (after Tsiotras, 2004)."
    )
    sub = parser.add_subparsers(dest="command", required=True)
    for command in COMMANDS:
        command.register(sub)
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


__all__ = ["build_parser", "main"]
