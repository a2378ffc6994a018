"""Atomic result files: JSON without sentinel numbers, and figures."""

from __future__ import annotations

import contextlib
import csv
import errno
import io
import json
import math
import os
import re
import tempfile
from collections.abc import Iterator
from pathlib import Path
from typing import Any, TypeVar

import numpy as np


T = TypeVar("T")

_DECIMAL = re.compile(r"[+-]?(?:\d+\.?\d*|\.\d+)(?:[eE][+-]?\d+)?", re.ASCII)
_SPECIAL = ("nan", "inf", "infinity")


def parse_number(text: str) -> float:
    """The number a data file's cell or an option writes: a decimal number (ASCII digits, a
    point, an exponent) or Python's ``nan`` and ``inf`` words, which callers refuse where a
    value must be finite. Raises `ValueError` for anything else, including what Python's
    `float` reads but a data file does not mean: digit groups (``4_0`` is 40 to Python) and
    digits of other scripts."""
    t = text.strip()
    if _DECIMAL.fullmatch(t) or t.lower().lstrip("+-") in _SPECIAL:
        return float(t)
    raise ValueError(f"not a number: {text!r}")


def _process_umask() -> int:
    """The process's file-creation mask (read by setting and restoring it, once, at import,
    before any thread of vehsim's could create a file meanwhile)."""
    mask = os.umask(0o022)
    os.umask(mask)
    return mask


_UMASK = _process_umask()
FILE_MODE = 0o666 & ~_UMASK
"""Permissions of the files vehsim writes: those of any new file (0644 under the usual
umask 022), so that a colleague on a shared machine can read them. `tempfile.mkstemp`
alone would leave 0600."""


def _jsonable(obj: Any) -> Any:
    if isinstance(obj, dict):
        return {str(k): _jsonable(v) for k, v in obj.items()}
    if isinstance(obj, list | tuple):
        return [_jsonable(v) for v in obj]
    if hasattr(obj, "__array__") and not isinstance(obj, str | bytes):
        arr = np.asarray(obj)
        if arr.ndim == 0:
            return _jsonable(arr.item())
        return [_jsonable(v) for v in arr.tolist()]
    if isinstance(obj, float) and not math.isfinite(obj):
        return None  # JSON has no NaN or inf: null, beside the status that says why
    if isinstance(obj, np.integer):
        return int(obj)
    if isinstance(obj, np.floating):
        return _jsonable(float(obj))
    return obj


@contextlib.contextmanager
def atomic_path(path: str | os.PathLike) -> Iterator[str]:
    """Yield a temporary file name beside ``path`` (its folder created if needed); what is
    written there replaces ``path`` by a rename when the block ends, with the permissions
    `FILE_MODE` of any new file (set again before the rename, for writers that recreate the
    temporary file), and is removed if the block raises (an error of the rename naming
    ``path``)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    try:
        os.fchmod(fd, FILE_MODE)
    finally:
        os.close(fd)
    try:
        yield tmp
        os.chmod(tmp, FILE_MODE)
        try:
            os.replace(tmp, path)
        except OSError as e:  # name the file asked for, not the temporary one
            raise OSError(e.errno, e.strerror, str(path)) from None
    except BaseException:
        if os.path.exists(tmp):
            os.unlink(tmp)
        raise


def read_text(path: str | os.PathLike) -> str:
    """The text of a UTF-8 file (newlines as written, for the `csv` module; a leading byte
    order mark, as spreadsheet programs write, dropped); a file that is not UTF-8 text is
    refused naming it."""
    try:
        with open(path, newline="", encoding="utf-8-sig") as f:
            return f.read()
    except UnicodeDecodeError as e:
        raise ValueError(f"{path}: not a UTF-8 text file (byte {e.start}: {e.reason}); "
                         "save it as UTF-8 CSV") from None
    except OSError as e:  # a device error, no permission, ...: name the file
        raise ValueError(f"{path}: cannot read it ({e.strerror or e})") from None


def csv_rows(path: str | os.PathLike) -> list[list[str]]:
    r"""The rows of a CSV file (`read_text`): lines may end in ``\n``, ``\r\n`` or a lone
    ``\r`` (old Mac files); what the `csv` module cannot read (a field past its size limit)
    is refused naming the file and line."""
    reader = csv.reader(io.StringIO(read_text(path), newline=""))
    try:
        return list(reader)
    except csv.Error as e:
        raise ValueError(f"{path}:{reader.line_num}: cannot read this line as CSV ({e})"
                         ) from None


def write_atomic(path: str | os.PathLike, data: str | bytes) -> Path:
    """Write ``data`` to ``path`` atomically (temporary file in the same folder, then rename)."""
    return write_atomic_files({path: data})[0]


def write_atomic_files(files: dict) -> list[Path]:
    """Write several files (``{path: text or bytes}``) together: every temporary file is
    written before any is renamed into place, so that a failure while writing leaves none
    of them (a pair of files that belong together, such as a CSV and its side file), and a
    folder in any file's place is refused before the first rename (`IsADirectoryError`
    naming it). A rename that fails for another reason (rare: the folder's permissions
    changed meanwhile) can still leave the files renamed before it."""
    for path in files:
        if Path(path).is_dir():
            raise IsADirectoryError(errno.EISDIR, os.strerror(errno.EISDIR), str(path))
    with contextlib.ExitStack() as stack:
        for path, data in files.items():
            tmp = stack.enter_context(atomic_path(path))
            with open(tmp, "wb" if isinstance(data, bytes) else "w") as f:
                f.write(data)
                f.flush()
                os.fsync(f.fileno())
    return [Path(p) for p in files]


def json_text(obj: Any) -> str:
    """``obj`` (dicts, lists, numbers, arrays) as indented JSON text."""
    return json.dumps(_jsonable(obj), indent=2) + "\n"


def write_json(path: str | os.PathLike, obj: Any) -> Path:
    """Write ``obj`` (dicts, lists, numbers, arrays) as indented JSON, atomically."""
    return write_atomic(path, json_text(obj))


def figure_bytes(fig, path: str | os.PathLike, dpi: int = 130) -> bytes:
    """A matplotlib figure rendered in the format ``path``'s suffix names (PNG without one)."""
    import io

    buf = io.BytesIO()
    fig.savefig(buf, format=Path(path).suffix.lstrip(".") or "png", dpi=dpi, bbox_inches="tight")
    return buf.getvalue()


def save_figure(fig, path: str | os.PathLike, dpi: int = 130) -> Path:
    """Save a matplotlib figure atomically (PNG)."""
    return write_atomic(path, figure_bytes(fig, path, dpi))


def write_json_and_figure(json_path: str | os.PathLike, obj: Any,
                          figure_path: str | os.PathLike, fig) -> list[Path]:
    """A result's JSON record and its figure, written together (`write_atomic_files`): a
    figure that cannot be rendered or written leaves no record without it."""
    return write_atomic_files({json_path: json_text(obj),
                               figure_path: figure_bytes(fig, figure_path)})
