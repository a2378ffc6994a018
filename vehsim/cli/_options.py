"""The command line's one validation path: option types that check while parsing.

Each factory returns an ``argparse`` ``type=`` callable. A value that does not parse or is
out of its range raises `argparse.ArgumentTypeError`, which argparse reports as
``vehsim CMD: error: argument --speed: must be a finite number in (0, 100] m/s, got 'nan'``
with exit status 2: the option as the user typed it, its allowed range, before any
compilation and before any file is written. Checks that involve several options (an output
extension against a format, options that need each other) raise `ValueError` from the
command before its first computation; `vehsim.cli.main` turns that into the same exit
status.
"""

from __future__ import annotations

import argparse
import math
import os
import tempfile
from pathlib import Path


def _bound(x) -> str:
    """A bound as written: integers in full (a seed's 2147483647), other numbers by `g`."""
    return str(x) if isinstance(x, int) else f"{x:g}"


def _interval(lower, upper, lower_open, upper_open, unit) -> str:
    lo = "-inf" if lower is None else _bound(lower)
    hi = "inf" if upper is None else _bound(upper)
    text = f"{'(' if lower_open or lower is None else '['}{lo}, {hi}" \
           f"{')' if upper_open or upper is None else ']'}"
    return f"{text} {unit}".rstrip()


def number(lower: float | None = None, upper: float | None = None, *, lower_open=False,
           upper_open=False, unit: str = "", allow_inf: bool = False):
    """A finite float in the interval (``inf`` too if `allow_inf`, for "never")."""
    allowed = _interval(lower, upper, lower_open, upper_open, unit)
    what = "a number (or inf)" if allow_inf else "a finite number"

    def parse(text: str) -> float:
        from .._io import parse_number

        try:
            x = parse_number(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"must be {what} in {allowed}, got {text!r}") \
                from None
        infinite_ok = allow_inf and math.isinf(x) and x > 0
        bad = math.isnan(x) or (math.isinf(x) and not infinite_ok) or (not infinite_ok and (
            (lower is not None and (x < lower or (lower_open and x == lower)))
            or (upper is not None and (x > upper or (upper_open and x == upper)))))
        if bad:
            raise argparse.ArgumentTypeError(f"must be {what} in {allowed}, got {text!r}")
        return x

    return parse


def integer(lower: int | None = None, upper: int | None = None):
    """An integer in ``[lower, upper]``."""
    allowed = _interval(lower, upper, False, False, "")

    def parse(text: str) -> int:
        try:
            n = int(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"must be an integer in {allowed}, got {text!r}") \
                from None
        if (lower is not None and n < lower) or (upper is not None and n > upper):
            raise argparse.ArgumentTypeError(f"must be an integer in {allowed}, got {text!r}")
        return n

    return parse


def choice_of(names, what: str):
    """One of `names` (a case-sensitive word), the message listing them."""
    names = tuple(names)

    def parse(text: str) -> str:
        if text not in names:
            raise argparse.ArgumentTypeError(
                f"unknown {what} {text!r}; one of: {', '.join(names)}")
        return text

    parse.names = names  # the allowed words, for help texts and docs checks
    return parse


def output_file(option: str, path: str, suffixes: dict[str, str]) -> str:
    """The format of an output file from its extension (`suffixes`: extension -> format),
    refused (naming `option`) when the extension is none of them."""
    suffix = Path(path).suffix.lower()
    if suffix not in suffixes:
        raise ValueError(f"{option}: the file name must end in "
                         f"{' or '.join(suffixes)} (the format follows it), got {path!r}")
    return suffixes[suffix]


def _refuse_empty(option: str, path) -> None:
    """An empty name would be read as the current folder ('.')."""
    if isinstance(path, str) and not path.strip():
        raise ValueError(f"{option}: an empty file name")


def outputs_spare_inputs(folder, names, inputs) -> None:
    """Refuse, before any work, an output folder where one of the command's files `names`
    would replace one of its `inputs` (a braking CSV) or an input's side file (``NAME.json``
    beside ``NAME.csv``): ``vehsim estimate DIR/estimate.csv --out DIR`` would overwrite the
    record's wheel data with its results."""
    for name in names:
        target = (Path(folder) / name).resolve()
        for f in inputs:
            f = Path(f).resolve()
            if target in (f, f.with_suffix(".json")):
                raise ValueError(f"--out: writing {name} in {str(folder)!r} would replace "
                                 f"{'the input' if target == f else 'the side file of'} "
                                 f"{str(f)!r}; give another output folder")


def writable_output(option: str, path, kind: str) -> None:
    """Refuse, naming `option`, an output `path` that cannot be written, before any work:
    a `kind` 'folder' that exists as a file, a 'file' that exists as a folder, or one whose
    nearest existing folder is a file or cannot be written in (permissions, a read-only
    file system, or a folder such as /proc that takes no files, found by making and removing
    a probe file there: permission bits do not bind the superuser). Leaves nothing behind."""
    _refuse_empty(option, path)
    path = Path(path)
    if kind == "folder" and path.exists() and not path.is_dir():
        raise ValueError(f"{option}: {str(path)!r} exists and is not a folder; give a folder "
                         "to write the results in")
    if kind == "file" and path.is_dir():
        raise ValueError(f"{option}: {str(path)!r} is a folder; give a file name")
    where = path if kind == "folder" else path.parent
    existing = where if str(where) else Path(".")
    while not existing.exists() and existing != existing.parent:
        existing = existing.parent
    if not existing.is_dir():
        raise ValueError(f"{option}: cannot create {str(path)!r}: {str(existing)!r} is a file, "
                         "not a folder")
    if not os.access(existing, os.W_OK | os.X_OK):
        raise ValueError(f"{option}: cannot write in {str(existing)!r} (no permission, or a "
                         "read-only file system)")
    try:
        fd, probe = tempfile.mkstemp(dir=existing, prefix=".vehsim-probe-")
    except OSError as e:
        raise ValueError(f"{option}: cannot write in {str(existing)!r}: no file can be created "
                         f"there ({e.strerror or e})") from None
    os.close(fd)
    os.unlink(probe)


def input_file(option: str, path) -> Path:
    """`path` as a `Path`, after refusing, naming `option`, one that is missing or a folder."""
    _refuse_empty(option, path)
    path = Path(path)
    if path.is_dir():
        raise ValueError(f"{option}: {str(path)!r} is a folder; give a file")
    if not path.is_file():
        raise ValueError(f"{option}: no such file {str(path)!r}")
    return path


__all__ = ["choice_of", "input_file", "integer", "number", "output_file", "writable_output"]
