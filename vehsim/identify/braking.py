r"""Braking data: the file format, a validating loader, and a writer.

**Format.** A braking is a CSV file with one header row of column names and one row per
sample (report section 2.2, Figs. 8-9: wheel-force-transducer force, wheel and vehicle
speed), plus a side file of metadata with the same stem and suffix ``.json``:

| column  | unit   | meaning                                                          |
|---------|--------|------------------------------------------------------------------|
| `t`     | s      | time, strictly increasing                                         |
| `v`     | m/s    | vehicle (wheel-centre) speed                                      |
| `omega` | rad/s  | wheel angular speed                                               |
| `F_x`   | N      | longitudinal friction force, $F_x<0$ when braking                 |
| `F_n`   | N      | normal load, $\ge 0$                                             |
| `T_b`   | N m    | brake torque, $\ge 0$ (optional; needed for closed-loop fits)     |

Side file (JSON): ``{"r": rolling radius [m], "m": mass share [kg], "J": wheel inertia
[kg m^2], "units": {...}, "description": ...}``; only ``r`` is required (``m`` and ``J``
are needed for closed-loop fits). Extra columns and keys are kept but ignored.

The loader never drops or repairs anything: any problem raises `ValueError` naming the
file, the row (1-based data row; the header is row 0) and the column.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import equinox as eqx
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from .._checks import (
    check_count,
    check_finite,
    check_nonnegative,
    check_positive,
    check_type,
    is_concrete,
)
from .._constants import SAMPLE_STEP_RANGE
from .._io import csv_rows, json_text, parse_number, write_atomic_files


REQUIRED_COLUMNS = ("t", "v", "omega", "F_x", "F_n")
OPTIONAL_COLUMNS = ("T_b",)
UNITS = {"t": "s", "v": "m/s", "omega": "rad/s", "F_x": "N", "F_n": "N", "T_b": "N m",
         "r": "m", "m": "kg", "J": "kg m^2"}


class BrakingData(eqx.Module):
    r"""One braking: samples of $t, v, \omega, F_x, F_n$ (and $T_b$), and the wheel data.

    Arrays are float64 of equal length $T$; `T_b`, `m`, `J` may be `None` (open-loop fits
    only). `name` is for reports.
    """

    t: Float[Array, " T"]
    v: Float[Array, " T"]
    omega: Float[Array, " T"]
    F_x: Float[Array, " T"]
    F_n: Float[Array, " T"]
    r: Float[Array, ""]
    T_b: Float[Array, " T"] | None = None
    m: Float[Array, ""] | None = None
    J: Float[Array, ""] | None = None
    name: str = eqx.field(static=True, default="braking")

    def __check_init__(self):
        shape = np.shape(self.t)
        for column in ("v", "omega", "F_x", "F_n", "T_b"):
            x = getattr(self, column)
            if x is not None and np.shape(x) != shape:
                raise ValueError(f"BrakingData.{column} must have t's shape {shape} (one value "
                                 f"per sample), got {np.shape(x)}")
        if len(shape) != 1 or shape[0] < 2:
            raise ValueError(f"BrakingData.t must be a 1-D array of at least 2 times [s], got "
                             f"shape {shape}")
        # what load_braking and save_braking refuse in a file, refused in memory too
        for column in ("t", "omega", "F_x"):
            check_finite("BrakingData", column, getattr(self, column))
        for column in NONNEGATIVE:
            if getattr(self, column) is not None:
                check_nonnegative("BrakingData", column, getattr(self, column))
        if is_concrete(self.t) and np.any(np.diff(np.asarray(self.t)) <= 0):
            i = int(np.argmax(np.diff(np.asarray(self.t)) <= 0)) + 1
            single = np.asarray(self.t).dtype == np.float32
            raise ValueError(f"BrakingData.t must increase strictly, got {float(self.t[i]):.9g} "
                             f"after {float(self.t[i - 1]):.9g} (index {i})"
                             + (": in float32, times this close round into one; call "
                                "jax.config.update('jax_enable_x64', True) first"
                                if single else ""))
        check_positive("BrakingData", "r", self.r)
        for name in ("m", "J"):
            if getattr(self, name) is not None:
                check_positive("BrakingData", name, getattr(self, name))

    @property
    def v_r(self):
        r"""Relative velocity $v_r = r\omega - v$ [m/s]."""
        return self.r * self.omega - self.v

    def __len__(self) -> int:
        return int(self.t.shape[0])


def _fail(path, row, column, message):
    where = f"row {row}, column {column!r}" if row is not None else f"column {column!r}"
    raise ValueError(f"{path}: {where}: {message}")


def load_braking(path, r: float | None = None, name: str | None = None) -> BrakingData:
    """Read and validate a braking CSV (and its ``.json`` side file).

    **Arguments:**

    - `path`: the CSV file.
    - `r`: rolling radius [m], overriding (or replacing a missing) side file.
    - `name`: a label (default: the file stem).

    **Raises:** `ValueError` naming the row and column for: a missing required column, a
    row with the wrong number of fields, a non-numeric, NaN or infinite value, time not
    strictly increasing, a negative speed, normal load or brake torque, fewer than 3 rows, or a
    missing/invalid radius.
    """
    path = braking_path(path)
    values = _read_columns(path)
    _check_columns(path, values)
    scalars = _read_wheel_data(path, r)
    return BrakingData(
        t=jnp.asarray(values["t"]), v=jnp.asarray(values["v"]),
        omega=jnp.asarray(values["omega"]), F_x=jnp.asarray(values["F_x"]),
        F_n=jnp.asarray(values["F_n"]),
        T_b=jnp.asarray(values["T_b"]) if "T_b" in values else None,
        name=path.stem if name is None else name, **scalars,
    )


def _read_columns(path: Path, required=REQUIRED_COLUMNS, optional=OPTIONAL_COLUMNS,
                  may_be_missing=()) -> dict[str, np.ndarray]:
    """The `required` and present `optional` columns of the CSV, each value a finite number
    (in the columns `may_be_missing`, an empty field or ``nan`` reads as NaN: a missing
    sample)."""
    rows = csv_rows(path)
    if not rows:
        raise ValueError(f"{path}: empty file (expected a header row)")
    header, rows = [h.strip() for h in rows[0]], rows[1:]
    while rows and not rows[-1]:  # blank lines at the end of the file are not rows
        rows.pop()
    for col in required:
        if col not in header:
            _fail(path, None, col, f"missing required column (header has {header}; "
                  f"required {list(required)})")
    if len(set(header)) != len(header):
        raise ValueError(f"{path}: duplicate column names in header {header}")
    wanted = [c for c in tuple(required) + tuple(optional) if c in header]
    index = {c: header.index(c) for c in wanted}
    values = {c: np.empty(len(rows)) for c in wanted}
    for i, row in enumerate(rows, 1):
        if len(row) != len(header):
            col = header[len(row)] if len(row) < len(header) else "<extra>"
            _fail(path, i, col, f"row has {len(row)} fields, header has {len(header)} "
                  "(inconsistent lengths)")
        for c in wanted:
            text = row[index[c]].strip()
            if c in may_be_missing and text.lower() in ("", "nan"):
                values[c][i - 1] = math.nan
                continue
            try:
                x = parse_number(text)
            except ValueError:
                _fail(path, i, c, f"not a number: {text!r}")
            if not math.isfinite(x):
                _fail(path, i, c, f"value must be finite, got {text!r} (NaN or inf)")
            values[c][i - 1] = x
    return values


def braking_path(path) -> Path:
    """`path` as a `Path`, after refusing a folder or a missing file, naming it."""
    path = Path(path)
    if path.is_dir():
        raise IsADirectoryError(f"{path}: a folder, not a braking file (CSV)")
    if not path.is_file():
        raise FileNotFoundError(f"{path}: no such braking file")
    return path


def check_sample_step(path, t) -> None:
    """Refuse a record whose mean step lies outside `SAMPLE_STEP_RANGE`, naming column t."""
    h = (float(t[-1]) - float(t[0])) / (len(t) - 1)
    lo, hi = SAMPLE_STEP_RANGE
    if not lo <= h <= hi:
        _fail(path, 2, "t", f"the sample step is {h:g} s; it must lie in [{lo:g}, {hi:g}] s "
              "(100 kHz to 1 Hz): is the time in seconds?")


def _check_columns(path: Path, values: dict[str, np.ndarray]) -> None:
    """At least 3 rows, time strictly increasing at a mean step in `SAMPLE_STEP_RANGE`,
    speed, load and torque not negative."""
    if len(values["t"]) < 3:
        raise ValueError(f"{path}: need at least 3 data rows, got {len(values['t'])}")
    dt = np.diff(values["t"])
    if np.any(dt <= 0):
        i = int(np.argmax(dt <= 0)) + 2
        _fail(path, i, "t", f"time must increase strictly, got {float(values['t'][i - 1]):g} after "
              f"{float(values['t'][i - 2]):g}")
    check_sample_step(path, values["t"])
    check_magnitudes(path, values)


NONNEGATIVE = {"v": "the forward speed of a braking", "F_n": "a load magnitude",
               "T_b": "a torque magnitude"}
"""The columns of a braking record that may not be negative, and what each holds."""


def check_magnitudes(path, values: dict[str, np.ndarray]) -> None:
    """Refuse the first negative value of a `NONNEGATIVE` column, naming its row."""
    for c, what in NONNEGATIVE.items():
        if c in values and np.any(values[c] < 0):
            i = int(np.argmax(values[c] < 0)) + 1
            _fail(path, i, c, f"must be >= 0 ({what}), got {float(values[c][i - 1]):g}")


SIDE_RANGES = {"r": 5.0, "m": math.inf, "J": math.inf}
"""Upper bounds of the side file's wheel radius [m], mass [kg] and inertia [kg m^2] (the
lower bound of each is 0, open; the radius's as the command line's ``--radius``)."""


def read_side_file(path: str | Path) -> dict:
    """The wheel data of a record's side file (``NAME.json`` beside ``NAME.csv``): a JSON
    object whose `r`, `m`, `J` (each optional) are numbers in (0, `SIDE_RANGES`]; ``{}``
    when there is no side file. A bad file is refused naming it and the key."""
    side = Path(path).with_suffix(".json")
    if side.is_dir():  # not a side file the record lacks: one that cannot be read
        raise ValueError(f"{side}: the record's side file is a folder; it must be a JSON "
                         "file of the wheel data, or absent")
    if not side.is_file():
        return {}
    try:
        text = side.read_text()
    except UnicodeDecodeError as e:
        raise ValueError(f"{side}: invalid JSON side file: {e}") from None
    except OSError as e:
        raise ValueError(f"{side}: cannot read the side file: {e.strerror}") from None
    try:
        meta = json.loads(text)
    except RecursionError:
        raise ValueError(f"{side}: invalid JSON side file: nested too deeply; it must be a "
                         "JSON object of numbers") from None
    except ValueError as e:  # a JSONDecodeError, or an integer of thousands of digits
        raise ValueError(f"{side}: invalid JSON side file: {e}") from None
    if not isinstance(meta, dict):
        raise ValueError(f"{side}: the side file must be a JSON object such as "
                         f'{{"r": 0.3, "m": 350, "J": 1.0}}, got a {type(meta).__name__}')
    out = {}
    for key, upper in SIDE_RANGES.items():
        value = meta.get(key)
        if value is None:
            continue
        if isinstance(value, bool) or not isinstance(value, int | float):
            raise ValueError(f"{side}: {key!r} must be a number, got {value!r}")
        try:
            x = float(value)
        except OverflowError:  # an integer of hundreds of digits
            x = math.inf
        if not (math.isfinite(x) and 0 < x <= upper):
            span = f"(0, {upper:g}]" if math.isfinite(upper) else "(0, inf)"
            raise ValueError(f"{side}: {key!r} [{UNITS[key]}] must lie in {span}, got {x:g}")
        out[key] = x
    return out


def _read_wheel_data(path: Path, r: float | None) -> dict:
    """`r` (required), `m`, `J` from the side file (`r` overridden by the argument)."""
    side = path.with_suffix(".json")
    meta = read_side_file(path)  # its values checked there
    if r is not None:
        if isinstance(r, bool):  # float(True) is a 1 m wheel
            raise ValueError(f"load_braking: r must be a number, got {r!r}")
        try:
            meta["r"] = float(r)
        except (TypeError, ValueError):
            raise ValueError(f"load_braking: r must be a number, got {r!r}") from None
        if not (math.isfinite(meta["r"]) and 0 < meta["r"] <= SIDE_RANGES["r"]):
            raise ValueError(f"load_braking: r [m] must lie in (0, {SIDE_RANGES['r']:g}], got "
                             f"{meta['r']:g}")
    if "r" not in meta:
        raise ValueError(f"{path}: wheel radius 'r' [m] missing: put it in the side file "
                         f"{side.name}, or give it (--radius on the command line, r= to "
                         "load_braking)")
    return {key: jnp.asarray(x) for key, x in meta.items()}


def save_braking(data: BrakingData, path, metadata: dict | None = None, digits: int = 10):
    """Write `data` as CSV (``%.{digits}g``) plus its ``.json`` side file, both or neither,
    atomically. What `load_braking` would refuse (a NaN, time not increasing, a negative
    load, a radius outside its range, metadata that is not JSON) is refused before anything
    is written, as are `digits` that round the times into ties, `metadata` that would
    replace the checked ``r``, ``m``, ``J`` or ``units``, and a `path` ending in ``.json``
    (the side file's own name)."""
    path = Path(path)
    check_type("save_braking", "data", data, BrakingData)
    if path.suffix.lower() == ".json":
        raise ValueError(f"save_braking: {path} is the name of a side file; give the CSV's "
                         f"path ({path.with_suffix('.csv')}), its side file goes beside it")
    check_count("save_braking", "digits", digits, sep=": ")
    reserved = sorted({"r", "m", "J", "units"} & set(metadata or {}))
    if reserved:
        raise ValueError(f"save_braking: metadata may not set {', '.join(reserved)}: the side "
                         "file's wheel data and units come from the record (checked); not saved")
    cols = list(REQUIRED_COLUMNS) + (["T_b"] if data.T_b is not None else [])
    values = {c: np.asarray(getattr(data, c), dtype=float) for c in cols}
    for c, a in values.items():
        if not np.all(np.isfinite(a)):
            i = int(np.argmin(np.isfinite(a))) + 1
            _fail(path, i, c, f"value must be finite, got {a[i - 1]:g}; not saved")
    _check_columns(path, values)
    meta = {}
    for key in ("r", "m", "J"):
        if getattr(data, key) is not None:
            meta[key] = float(getattr(data, key))
            if not (math.isfinite(meta[key]) and 0 < meta[key] <= SIDE_RANGES[key]):
                raise ValueError(f"save_braking: {key} [{UNITS[key]}] must lie in "
                                 f"(0, {SIDE_RANGES[key]:g}], got {meta[key]:g}; not saved")
    meta["units"] = {k: UNITS[k] for k in cols + list(meta)}
    meta.update(metadata or {})
    try:
        side = json_text(meta)
    except TypeError as e:
        raise ValueError(f"save_braking: metadata must be JSON (numbers, strings, lists, "
                         f"dicts): {e}; not saved") from None
    fmt = f"%.{digits}g"
    arrays = list(values.values())
    try:  # what load_braking would read back
        _check_columns(path, {c: np.char.mod(fmt, a).astype(float) for c, a in values.items()})
    except ValueError as e:
        raise ValueError(f"save_braking: digits={digits} round the record into one that "
                         f"load_braking refuses ({e}); not saved") from None
    lines = [",".join(cols)] + [",".join(fmt % a[k] for a in arrays) for k in range(len(data))]
    write_atomic_files({path: "\n".join(lines) + "\n", path.with_suffix(".json"): side})
    return path


def shipped_brakings() -> dict[str, Path]:
    """The synthetic brakings shipped with vehsim: name -> CSV path (see their side files)."""
    folder = Path(__file__).resolve().parent.parent / "data" / "brakings"
    return {p.stem: p for p in sorted(folder.glob("*.csv"))}


def slip_sign_note(data: BrakingData) -> str | None:
    r"""A sentence when a braking's force and slip disagree the way mistaken units or signs
    make them (None otherwise): on the samples that slip ($|v| > 1$ m/s, $|s| > 0.02$ with
    $s = (\omega r - v)/v$) and carry force ($|F_x|$ above 5 % of its peak), the force
    should push the way the slip does (eq. 22's steady force has the sign of the slip); a
    record whose force opposes it on most of them, or whose slip passes 1.5, is not a
    braking in SI units (omega in rpm, for example, gives slips near 9)."""
    reasons = slip_unit_reasons(data.v, data.omega, float(np.asarray(data.r)), data.F_x)
    if not reasons:
        return None
    return (f"{data.name}: " + " and ".join(reasons) + "; check the units and signs "
            "(omega in rad/s, v in m/s, r in m, F_x > 0 driving and < 0 braking)")


def slip_unit_reasons(v, omega, r: float, F=None) -> list[str]:
    """Why a record's slip looks like mistaken units or signs (`slip_sign_note`'s tests, on
    the samples moving faster than 1 m/s with a measured wheel speed): the force opposing
    the slip on most slipping, loaded samples (when the force `F` is given), a slip beyond
    1.5. Empty when neither."""
    v, omega = np.asarray(v, float), np.asarray(omega, float)
    moving = (np.abs(v) > 1.0) & np.isfinite(omega)
    if not moving.any():
        return []
    s = (omega[moving] * r - v[moving]) / v[moving]
    reasons = []
    if F is not None:
        F = np.asarray(F, float)
        Fm = F[moving]
        loaded = (np.abs(s) > 0.02) & (np.abs(Fm) > 0.05 * np.max(np.abs(F)))
        opposed = (float(np.mean(np.sign(Fm[loaded]) != np.sign(s[loaded]))) if loaded.any()
                   else 0.0)
        if opposed > 0.5:
            reasons.append(f"the force opposes the slip on {100 * opposed:.0f} % of the "
                           "slipping samples")
    if np.max(np.abs(s)) > 1.5:
        reasons.append(f"the slip (omega r - v)/v reaches {np.max(np.abs(s)):.3g}")
    return reasons
