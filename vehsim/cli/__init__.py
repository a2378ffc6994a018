"""The ``vehsim`` command line (also ``python -m vehsim``).

One module per subcommand (`reproduce`, `sweep`, `fit`, `optimise`, `brake`, `estimate`,
`tire`, `drive`), each with ``register(subparsers)`` adding a parser whose ``func`` is called with the
parsed arguments.
A `ValueError` or an `OSError` (a missing file, a folder given for a file) ends the
command with exit status 2 and the message.
Long batched work shows progress on stderr (`vehsim.progress`) unless ``--no-progress``.
Compiled programs are kept in JAX's persistent compilation cache
(`vehsim._compilation.command_line_cache`, the layer above the solvers that also keeps
their exported programs), so that a second run starts in seconds, unless
``--no-compilation-cache`` or ``VEHSIM_NO_COMPILATION_CACHE=1``.
"""

from __future__ import annotations

import argparse
import gc
import re
import sys

from . import brake, drive, estimate, fit, optimise, reproduce, sweep, tire
from ._options import writable_output


COMMANDS = (reproduce, sweep, fit, optimise, brake, estimate, tire, drive)


class _Parser(argparse.ArgumentParser):
    """argparse, with every word that starts with a minus and a digit, ``inf`` or ``nan``
    read as a value: ``--patch -5,2,3,0.5``, ``--loads -100,3800`` and ``--speed -inf``
    (argparse alone takes only single finite negative numbers for values, and reads the
    others as unknown options), so that the option's own range check names it. No vehsim
    option is spelled that way. Its subcommands' parsers are of the same class."""

    def __init__(self, *args, **kwargs):
        super().__init__(*args, **kwargs)
        self._negative_number_matcher = re.compile(r"^-(\.?\d|inf|nan)", re.IGNORECASE)


def build_parser() -> argparse.ArgumentParser:
    from .. import __version__
    from .._compilation import NO_CACHE_VARIABLE, default_cache_dir

    parser = _Parser(
        prog="vehsim", description="Differentiable vehicle simulation (after Tsiotras, 2004)."
    )
    parser.add_argument("--version", action="version", version=f"%(prog)s {__version__}")
    parser.add_argument("--no-progress", action="store_true",
                        help="no progress lines on stderr for long batched work")
    parser.add_argument("--no-compilation-cache", action="store_true",
                        help="compile every program afresh (the cache of compiled programs is "
                             f"on by default, in {default_cache_dir()}: set VEHSIM_CACHE_DIR "
                             f"to move it, {NO_CACHE_VARIABLE}=1 to turn it off, delete the "
                             "folder to clear it)")
    sub = parser.add_subparsers(dest="command", required=True)
    for command in COMMANDS:
        command.register(sub)
    return parser


def _jax_environment_error() -> str | None:
    """What is wrong with ``$JAX_NUM_CPU_DEVICES``, if anything (`cpu_devices_error`)."""
    from .._xla_cpu import cpu_devices_error

    return cpu_devices_error()


def main(argv: list[str] | None = None) -> int:
    import jax

    from .._compilation import cache_settings_restored, command_line_cache
    from ..progress import set_default

    jax.config.update("jax_enable_x64", True)
    try:
        args = build_parser().parse_args(argv)
    except SystemExit as e:  # bad input (status 2, argparse's message), --help, --version
        return int(e.code or 0)
    args.argv = list(sys.argv[1:] if argv is None else argv)
    problem = _jax_environment_error()
    if problem is not None:  # before JAX starts its backend (--help and --version need none)
        print(f"vehsim: error: {problem}", file=sys.stderr)
        return 2
    # in-process callers (a notebook, a test) get their cache settings and progress back
    with cache_settings_restored():
        try:
            args.cache_dir = command_line_cache(args.no_compilation_cache)
        except OSError as e:  # $VEHSIM_CACHE_DIR (or its default) a file, or not creatable
            print(f"vehsim: error: the compilation cache's folder cannot be used "
                  f"({e.strerror}: {e.filename!r}): set VEHSIM_CACHE_DIR to a writable "
                  "folder, or pass --no-compilation-cache", file=sys.stderr)
            return 2
        except ValueError as e:  # $VEHSIM_NO_COMPILATION_CACHE neither yes nor no
            print(f"vehsim: error: {e}", file=sys.stderr)
            return 2
        library_default = set_default(not args.no_progress)
        try:
            if getattr(args, "out", None) is not None:  # before any work
                writable_output("--out", args.out, getattr(args, "out_kind", "folder"))
            return int(args.func(args) or 0)
        except (ValueError, OSError) as e:  # bad input; a file that is missing, a folder, ...
            print(f"vehsim: error: {e}", file=sys.stderr)
            return 2
        finally:
            set_default(library_default)


def run() -> None:
    """The ``vehsim`` program: `main` with XLA's faster-compiling CPU code generator
    (`vehsim._xla_cpu.prefer_fast_compilation`, set before JAX starts), then exit with its
    status, skipping the interpreter's last garbage collections over the hundreds of
    thousands of objects that tracing left (`gc.freeze`): a noticeable part of a short
    command (docs/performance.md), and every file is written and closed by then."""
    from .._xla_cpu import prefer_fast_compilation

    prefer_fast_compilation()
    code = main()
    gc.freeze()
    raise SystemExit(code)


__all__ = ["build_parser", "main", "run"]
