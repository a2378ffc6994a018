"""Road files: centre line and widths as CSV (the racetrack-database layout), and the shipped
circuits.

The layout (TUMFTM racetrack-database): one row per centre-line point, columns ``x_m``,
``y_m`` (position [m]), ``w_tr_right_m``, ``w_tr_left_m`` (widths [m] from the centre line to
the right and left edges), named by a header line, either a comment (``# x_m,y_m,...``) or a
plain first line. Other ``#`` lines are comments; extra named columns are ignored, and a
row with more fields than the header names is refused. See docs/roads.md.
"""

from __future__ import annotations

import os
import re
from pathlib import Path

import numpy as np

from ._checks import check_type
from ._io import csv_rows, write_atomic
from .optimal.centreline import CentrelineRoad


COLUMNS = ("x_m", "y_m", "w_tr_right_m", "w_tr_left_m")
"""The columns a road file must have (others are ignored)."""

_TRACKS = Path(__file__).resolve().parent / "data" / "tracks"


def _header(fields: list[str]) -> list[str] | None:
    names = [f.strip() for f in fields]
    return names if {"x_m", "y_m"} <= set(names) else None


def read_road(path: str | os.PathLike, *, closed: bool = False, name: str | None = None,
              smoothing: float = 0.0) -> CentrelineRoad:
    """Read a road from a CSV file of centre-line points and widths.

    **Arguments:**

    - `path`: the file (columns ``x_m, y_m, w_tr_right_m, w_tr_left_m`` by name, in metres).
    - `closed`: a circuit (the first point is not repeated at the end).
    - `name`: the road's name (default: the file stem).
    - `smoothing`: as `CentrelineRoad.from_points` [m].

    **Raises:** `ValueError` naming the file and line for: no header, a missing column, a
    row with fewer fields than the header names or more (empty trailing fields aside), a
    value that is not a number, and the checks of `CentrelineRoad.from_points` (its rows
    given as the file's lines).
    """
    if not isinstance(closed, bool | np.bool_):  # "no" would read as a closed road
        raise TypeError(f"read_road: closed must be True or False, got {closed!r}")
    if isinstance(smoothing, bool) or not isinstance(smoothing, int | float | np.number):
        raise TypeError(f"read_road: smoothing [m] must be a number, got {smoothing!r}")
    path = Path(path)
    name = path.stem if name is None else name
    header, rows, lines = None, [], []
    for lineno, fields in enumerate(csv_rows(path), start=1):
        if not fields or not "".join(fields).strip():
            continue
        if fields[0].lstrip().startswith("#"):
            if header is None:
                fields = [fields[0].lstrip()[1:], *fields[1:]]
                header = _header(fields)
            continue
        if header is None:
            header = _header(fields)
            if header is None:
                raise ValueError(f"{path}:{lineno}: no header line naming the columns "
                                 f"{', '.join(COLUMNS)} before the first row")
            missing = [c for c in COLUMNS if c not in header]
            if missing:
                raise ValueError(f"{path}:{lineno}: missing column(s) {', '.join(missing)}; "
                                 f"found {', '.join(header)}")
            continue
        missing = [c for c in COLUMNS if c not in header]
        if missing:
            raise ValueError(f"{path}: missing column(s) {', '.join(missing)}; found "
                             f"{', '.join(header)}")
        twice = sorted({c for c in COLUMNS if header.count(c) > 1})
        if twice:
            raise ValueError(f"{path}: column(s) {', '.join(twice)} named twice in the header")
        if len(fields) < len(header):
            raise ValueError(f"{path}:{lineno}: {len(fields)} fields, the header names "
                             f"{len(header)}")
        if any(f.strip() for f in fields[len(header):]):  # 1,5 read as two numbers
            raise ValueError(f"{path}:{lineno}: {len(fields)} fields, the header names "
                             f"{len(header)} (a decimal comma? the decimal mark is '.')")
        row = []
        for col in COLUMNS:
            field = fields[header.index(col)].strip()
            try:
                row.append(float(field))
            except ValueError:
                raise ValueError(f"{path}:{lineno}: {col} is not a number: {field!r}") from None
        rows.append(row)
        lines.append(lineno)
    if header is None:
        raise ValueError(f"{path}: no header line naming the columns {', '.join(COLUMNS)}")
    data = np.asarray(rows, float).reshape(-1, 4)
    try:
        return CentrelineRoad.from_points(data[:, 0], data[:, 1], data[:, 2], data[:, 3],
                                          closed=closed, smoothing=smoothing, name=name)
    except ValueError as e:
        msg = str(e)
        msg = re.sub(r"\brows (\d+) and (\d+)",
                     lambda m: f"lines {lines[int(m[1])]} and {lines[int(m[2])]}", msg)
        msg = re.sub(r"\brow (\d+)", lambda m: f"line {lines[int(m[1])]}", msg)
        for key, col in (("width_right", "w_tr_right_m"), ("width_left", "w_tr_left_m"),
                         (", x ", ", x_m "), (", y ", ", y_m ")):
            msg = msg.replace(key, col)
        raise ValueError(f"{path}: {msg}") from None


def write_road(path: str | os.PathLike, road: CentrelineRoad) -> Path:
    """Write ``road`` as a CSV file in the layout `read_road` reads (atomically): its centre
    line and widths at its knots (about every 0.5 m; a closed road's last knot, equal to the
    first, left out), to nanometres."""
    check_type("write_road", "road", road, CentrelineRoad)
    if any(c in road.name for c in "\r\n"):
        raise ValueError(f"write_road: the road's name {road.name!r} holds a line break, "
                         "which its header line cannot")
    s = road.knots[:-1] if road.closed else road.knots
    x, y = road.position(s)
    wr, wl = road.width_right(s), road.width_left(s)
    head = (f"# {road.name}: {'closed' if road.closed else 'open'} road, centre line "
            f"{road.length:.6f} m long, written by vehsim\n# {','.join(COLUMNS)}\n")
    body = "".join(f"{a:.9f},{b:.9f},{c:.9f},{d:.9f}\n" for a, b, c, d in zip(x, y, wr, wl))
    return write_atomic(path, head + body)


def shipped_tracks() -> dict[str, Path]:
    """The circuits shipped with vehsim: name -> CSV path (source and licence in each
    file's header and in docs/roads.md)."""
    return {p.stem: p for p in sorted(_TRACKS.glob("*.csv"))}


def track(name: str, *, smoothing: float = 0.0) -> CentrelineRoad:
    """The shipped circuit ``name`` (e.g. ``"Oschersleben"``) as a closed `CentrelineRoad`."""
    tracks = shipped_tracks()
    if name not in tracks:
        raise ValueError(f"unknown track {name!r}; shipped: {sorted(tracks)}")
    return read_road(tracks[name], closed=True, name=name, smoothing=smoothing)
