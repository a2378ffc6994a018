"""Road files: centre line and widths as CSV (the racetrack-database layout), and the shipped
circuits.

The layout (TUMFTM racetrack-database): one row per centre-line point, columns ``x_m``,
``y_m`` (position [m]), ``w_tr_right_m``, ``w_tr_left_m`` (widths [m] from the centre line to
the right and left edges), named by a header line, either a comment (``# x_m,y_m,...``) or a
plain first line. Other ``#`` lines are comments; extra named columns are ignored, and a
row with more fields than the header names is refused. See docs/roads.md.

What the layout has no column for, `write_road` writes as comment lines that `read_road`
reads back (and other readers skip): whether the road is closed and its two gates,

    # closed: yes
    # start_gate: s=start n_min=edge n_max=edge speed=free
    # end_gate: s=41.5 n_min=-1.2 n_max=edge speed=12.5

(``s`` in metres, or ``start``/``end`` of the road, whose length a spline through the written
points reproduces only approximately; ``n_min``/``n_max`` the gate's lateral interval
in metres, or ``edge``, the road's edge there; ``speed`` in m/s, or ``free``).
"""

from __future__ import annotations

import os
import re
from pathlib import Path

import numpy as np

from ._checks import check_type
from ._io import csv_rows, parse_number, write_atomic
from .optimal.centreline import CentrelineRoad


COLUMNS = ("x_m", "y_m", "w_tr_right_m", "w_tr_left_m")
"""The columns a road file must have (others are ignored)."""

_TRACKS = Path(__file__).resolve().parent / "data" / "tracks"

_META = re.compile(r"^\s*#\s*(closed|start_gate|end_gate)\s*:(.*)$", re.IGNORECASE)
_GATE_KEYS = ("s", "n_min", "n_max", "speed")
_WORDS = {"s": ("start", "end"), "n_min": ("edge",), "n_max": ("edge",), "speed": ("free",)}


def _meta_line(meta: dict, key: str, value: str, where: str) -> None:
    """Record a ``# closed:`` / ``# start_gate:`` / ``# end_gate:`` line of a road file."""
    key = key.lower()
    if key in meta:
        raise ValueError(f"{where}: {key} given twice (first on line {meta[key][0]})")
    value = value.strip()
    if key == "closed":
        if value.lower() not in ("yes", "no", "true", "false"):
            raise ValueError(f"{where}: closed must be yes or no, got {value!r}")
        meta[key] = (where, value.lower() in ("yes", "true"))
        return
    gate = {}
    for token in value.split():
        name, eq, field = token.partition("=")
        name = name.lower()
        if not eq or name not in _GATE_KEYS:
            raise ValueError(f"{where}: {key}: {token!r} is not one of "
                             f"{', '.join(k + '=...' for k in _GATE_KEYS)}")
        if name in gate:
            raise ValueError(f"{where}: {key}: {name} given twice")
        if field.lower() in _WORDS[name]:
            gate[name] = field.lower()
            continue
        try:
            number = parse_number(field)
        except ValueError:
            raise ValueError(f"{where}: {key}: {name} must be a number or "
                             f"{' or '.join(_WORDS[name])}, got {field!r}") from None
        if not np.isfinite(number):
            raise ValueError(f"{where}: {key}: {name} must be finite, got {field!r}")
        gate[name] = number
    if "s" not in gate:
        raise ValueError(f"{where}: {key}: s=... (its arc length [m], start or end) missing")
    meta[key] = (where, gate)


def _gate(road: CentrelineRoad, where: str, fields: dict, end: bool):
    """The gate a file's ``# start_gate:`` / ``# end_gate:`` line describes on ``road``."""
    from .optimal.centreline import Gate

    def number(name, words):  # a word (or no field) -> None, its default
        value = fields.get(name)
        return words.get(value) if value is None or isinstance(value, str) else value

    s = number("s", {"start": 0.0, "end": road.length})
    try:
        return Gate.at(road, s, n_min=number("n_min", {}), n_max=number("n_max", {}),
                       speed=number("speed", {}))
    except ValueError as e:
        raise ValueError(f"{where}: {'end' if end else 'start'}_gate: {e}") from None


def _gate_text(road: CentrelineRoad, gate) -> str:
    """A gate as a road file's comment line reads it (`_meta_line`)."""
    wl, wr = float(road.width_left(gate.s)), float(road.width_right(gate.s))
    tol = 1e-9 * max(1.0, wl + wr)
    s = ("start" if gate.s == 0.0 else "end" if abs(gate.s - road.length) <= 1e-12 * road.length
         else repr(float(gate.s)))
    lo = "edge" if abs(gate.n_min + wr) <= tol else repr(float(gate.n_min))
    hi = "edge" if abs(gate.n_max - wl) <= tol else repr(float(gate.n_max))
    speed = "free" if gate.speed is None else repr(float(gate.speed))
    return f"s={s} n_min={lo} n_max={hi} speed={speed}"


def _header(fields: list[str]) -> list[str] | None:
    names = [f.strip() for f in fields]
    return names if {"x_m", "y_m"} <= set(names) else None


def _check_header(path: Path, header: list[str]) -> None:
    missing = [c for c in COLUMNS if c not in header]
    if missing:
        raise ValueError(f"{path}: missing column(s) {', '.join(missing)}; found "
                         f"{', '.join(header)}")
    twice = sorted({c for c in COLUMNS if header.count(c) > 1})
    if twice:
        raise ValueError(f"{path}: column(s) {', '.join(twice)} named twice in the header")


def read_road(path: str | os.PathLike, *, closed: bool | None = None, name: str | None = None,
              smoothing: float = 0.0) -> CentrelineRoad:
    """Read a road from a CSV file of centre-line points and widths.

    **Arguments:**

    - `path`: the file (columns ``x_m, y_m, w_tr_right_m, w_tr_left_m`` by name, in metres).
    - `closed`: a circuit (the first point is not repeated at the end); None (default): as
      the file's ``# closed:`` line says (`write_road` writes one), open if it has none.
    - `name`: the road's name (default: the file stem).
    - `smoothing`: as `CentrelineRoad.from_points` [m].

    The gates are the file's ``# start_gate:`` and ``# end_gate:`` lines where it has them
    (module docstring), else the full width at both ends.

    **Raises:** `ValueError` naming the file and line for: no header, a missing column, a
    row with fewer fields than the header names or more (empty trailing fields aside), a
    value that is not a number, a ``closed`` or gate line that cannot be read or a gate off
    the road, and the checks of `CentrelineRoad.from_points` (its rows given as the file's
    lines).
    """
    if closed is not None and not isinstance(closed, bool | np.bool_):  # "no" reads as True
        raise TypeError(f"read_road: closed must be True, False or None (as the file says), "
                        f"got {closed!r}")
    if isinstance(smoothing, bool) or not isinstance(smoothing, int | float | np.number):
        raise TypeError(f"read_road: smoothing [m] must be a number, got {smoothing!r}")
    path = Path(path)
    name = path.stem if name is None else name
    header, rows, lines, meta = None, [], [], {}
    for lineno, fields in enumerate(csv_rows(path), start=1):
        if not fields or not "".join(fields).strip():
            continue
        if fields[0].lstrip().startswith("#"):
            found = _META.match(",".join(fields))
            if found:
                _meta_line(meta, found[1], found[2], f"{path}:{lineno}")
                continue
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
        _check_header(path, header)
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
                row.append(parse_number(field))
            except ValueError:
                raise ValueError(f"{path}:{lineno}: {col} is not a number: {field!r}") from None
        rows.append(row)
        lines.append(lineno)
    if header is None:
        raise ValueError(f"{path}: no header line naming the columns {', '.join(COLUMNS)}")
    _check_header(path, header)  # a commented header and no rows
    data = np.asarray(rows, float).reshape(-1, 4)
    if closed is None:
        closed = meta.get("closed", (None, False))[1]
    try:
        road = CentrelineRoad.from_points(data[:, 0], data[:, 1], data[:, 2], data[:, 3],
                                          closed=bool(closed), smoothing=smoothing, name=name)
    except ValueError as e:
        msg = str(e)
        msg = re.sub(r"\brows (\d+) and (\d+)",
                     lambda m: f"lines {lines[int(m[1])]} and {lines[int(m[2])]}", msg)
        msg = re.sub(r"\brow (\d+)", lambda m: f"line {lines[int(m[1])]}", msg)
        for key, col in (("width_right", "w_tr_right_m"), ("width_left", "w_tr_left_m"),
                         (", x ", ", x_m "), (", y ", ", y_m ")):
            msg = msg.replace(key, col)
        raise ValueError(f"{path}: {msg}") from None
    if "start_gate" not in meta and "end_gate" not in meta:
        return road
    gates = [None if key not in meta else _gate(road, *meta[key], end=key == "end_gate")
             for key in ("start_gate", "end_gate")]
    return road.with_gates(*gates)


def write_road(path: str | os.PathLike, road: CentrelineRoad) -> Path:
    """Write ``road`` as a CSV file in the layout `read_road` reads (atomically): its centre
    line and widths at its knots (about every 0.5 m; a closed road's last knot, equal to the
    first, left out), to nanometres, and whether it is closed and its gates as comment lines
    (module docstring), so that `read_road` gives the road back."""
    check_type("write_road", "road", road, CentrelineRoad)
    if any(c in road.name for c in "\r\n"):
        raise ValueError(f"write_road: the road's name {road.name!r} holds a line break, "
                         "which its header line cannot")
    s = road.knots[:-1] if road.closed else road.knots
    x, y = road.position(s)
    wr, wl = road.width_right(s), road.width_left(s)
    head = (f"# {road.name}: {'closed' if road.closed else 'open'} road, centre line "
            f"{road.length:.6f} m long, written by vehsim\n"
            f"# closed: {'yes' if road.closed else 'no'}\n"
            f"# start_gate: {_gate_text(road, road.start)}\n"
            f"# end_gate: {_gate_text(road, road.end)}\n"
            f"# {','.join(COLUMNS)}\n")
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
