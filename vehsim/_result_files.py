"""Result files as a colleague meets them: a ``units`` block in every JSON the command line
writes, and `load_result` to read any of them back.

The units of a field come, in this order, from the writer's own table, from the names
vehsim knows (`vehsim.labelled.UNITS`, with its ``final_``/``max_``/``min_`` prefixes), and
from the unit suffix of the name (``stopping_distance_m`` [m], ``speed_m_s`` [m/s],
``wall_time_s`` [s], ``distance_over_bound`` and other ``*_over_*`` ratios, counts and
fractions [1], read from whole words of the name). Nested
records give dotted paths (``residuals.inf_pr``); the fields of a list of records
(``starts``, ``members``) are named once, as ``starts[].objective``.
"""

from __future__ import annotations

import json
import os
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np

from ._io import read_text
from .labelled import units_of


_SUFFIXES = (("_m_s", "m/s"), ("_m_s2", "m/s^2"), ("_rad_s", "rad/s"), ("_m", "m"),
             ("_s", "s"), ("_rad", "rad"), ("_deg", "deg"), ("_n", "N"), ("_nm", "N m"),
             ("_kg", "kg"), ("_hz", "Hz"), ("_pa", "Pa"))
_DIMENSIONLESS_WORDS = frozenset({"over", "ratio", "fraction", "count", "num", "number", "seed",
                                  "iterations", "segments", "nodes", "devices", "steps"})
"""Words of a name, between underscores, that make it a count or a ratio (unit 1)."""


def unit_of_name(name: str) -> str | None:
    """The unit vehsim reads off a field's name (module docstring), or None."""
    known = units_of(name)
    if known:
        return known["units"]
    lower = name.lower()
    for suffix, unit in _SUFFIXES:
        if lower.endswith(suffix):
            return unit
    words = set(lower.split("_"))
    if words & _DIMENSIONLESS_WORDS or {w[:-1] for w in words if w.endswith("s")} & \
            _DIMENSIONLESS_WORDS:  # whole words: "duration" holds "ratio" but is a time
        return "1"
    return None


def _is_number(x) -> bool:
    if isinstance(x, bool) or x is None or isinstance(x, str):
        return False
    if isinstance(x, int | float | np.number):
        return True
    if hasattr(x, "__array__"):
        return np.asarray(x).dtype.kind in "iuf"
    if isinstance(x, list | tuple) and x:
        return all(_is_number(v) or v is None for v in x) and any(_is_number(v) for v in x)
    return False


def units_block(record: Mapping[str, Any], units: Mapping[str, str] | None = None,
                strict: bool = True) -> dict[str, str]:
    """``{path: unit}`` for every numeric field of the JSON-ready `record` (module
    docstring); `units` gives the writer's own, by path or by name. A numeric field whose
    unit is unknown raises `ValueError` if `strict` (a writer that forgot one), else is
    left out."""
    units = dict(units or {})
    out: dict[str, str] = {}

    def walk(rec, prefix):
        for key, value in rec.items():
            if key == "units":
                continue
            path = f"{prefix}{key}"
            if isinstance(value, Mapping):
                if path in units:  # a group of fields sharing one unit (e.g. "states")
                    out[path] = units[path]
                    continue
                walk(value, path + ".")
            elif isinstance(value, list | tuple) and value and isinstance(value[0], Mapping):
                walk(value[0], path + "[].")
            elif _is_number(value):
                unit = units.get(path, units.get(key, unit_of_name(key)))
                if unit is None:
                    if strict:
                        raise ValueError(f"no unit known for the result field {path!r}")
                    continue
                out[path] = unit
    walk(record, "")
    return out


def with_units(record: Mapping[str, Any], units: Mapping[str, str] | None = None,
               strict: bool = True) -> dict[str, Any]:
    """`record` with its ``units`` block (`units_block`) as its last field."""
    return {**record, "units": units_block(record, units, strict)}


def _arrays(value):
    if isinstance(value, Mapping):
        return {k: _arrays(v) for k, v in value.items()}
    if isinstance(value, list):
        if value and all((isinstance(v, int | float) and not isinstance(v, bool)) or v is None
                         for v in value) and any(
                v is not None for v in value):
            return np.asarray([np.nan if v is None else v for v in value], dtype=float)
        if value and all(isinstance(v, list) for v in value):
            try:
                return np.asarray(value, dtype=float)
            except (ValueError, TypeError):
                pass
        return [_arrays(v) for v in value]
    return value


def load_result(path: str | os.PathLike):
    """Read back a result file vehsim wrote.

    A ``.json`` file gives a dict as written, with every list of numbers as a NumPy array
    (``null``, written for a non-finite number, as NaN) and its ``units`` block (path ->
    unit) as it is; a ``.nc`` file gives the `xarray.Dataset` (units in each variable's
    attributes; needs ``vehsim[xarray]``); a ``.csv`` braking record gives the
    `vehsim.identify.BrakingData` its loader reads."""
    path = Path(path)
    suffix = path.suffix.lower()
    if suffix not in (".json", ".nc", ".csv"):
        raise ValueError(f"{path}: vehsim reads back .json, .nc and .csv result files")
    if not path.exists():
        raise FileNotFoundError(f"{path}: no such file")
    if suffix == ".json":
        try:
            data = json.loads(read_text(path))
        except (json.JSONDecodeError, ValueError) as e:  # JSON's errors; not UTF-8 text
            raise ValueError(f"{path}: not a JSON file vehsim wrote ({e})") from None
        return _arrays(data)
    if suffix == ".nc":
        from .labelled import require_xarray

        xr = require_xarray()
        with xr.open_dataset(path) as ds:
            return ds.load()
    from .identify.braking import load_braking

    return load_braking(path)


__all__ = ["load_result", "unit_of_name", "units_block", "with_units"]
