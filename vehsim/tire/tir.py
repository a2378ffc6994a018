r"""Tyre property files (`.tir`): the section/key text that ADAMS, MF-Tyre, MFeval and Chrono read.

A file is a preamble of comment lines and a sequence of sections, each ``[NAME]`` followed by
``KEY = value`` lines; ``$`` and ``!`` start comments (whole lines, or after a value);
strings are quoted (``'meter'``); numbers may use a Fortran ``D`` exponent (``0.344D+0``);
a value may be empty (``KEY =``: present but not given). Sections may hold free rows instead
of keys (the ``[SHAPE]`` table of ``{radial width}`` pairs), kept as written.

The parsing here is a pure function of the text (`parse_tir`), and so is the writing
(`format_tir`): `read_tir` and `write_tir` only move text to and from the disk.
`format_tir(parse_tir(text)) == text` for any text `parse_tir` accepts (with ``\n`` line
endings), and a value changed
with `TirFile.replace` is written in the same layout.

**Units.** ``[UNITS]`` names the units of the *dimensional* keys (lengths, loads,
pressures, angles of the valid ranges, stiffnesses, speeds, masses, inertias); `TirFile.si`
converts those to SI. The Magic Formula coefficients are dimensionless by construction
(loads normalised by ``FNOMIN``, lengths by ``UNLOADED_RADIUS``, angles in radians in the
formulas), so they are read as written whatever ``[UNITS]`` says.

**Formula version** (`TirFile.version`): ``FITTYP`` decides when present (5, 6, 21, 52:
MF 5.2 / PAC2002; 61: MF 6.1; 62: MF 6.2), else ``PROPERTY_FILE_FORMAT = 'PAC2002'``
means MF 5.2. Anything else is refused.

**Checks** (all raise `TirError` naming the file, the line and the key): a line that is
neither a section, a key, a comment nor a row of a table section; a key given twice in a
section, or in two sections with different values; a second ``[UNITS]``; a unit or
formula version this module does not know; a missing required key (`REQUIRED`); a value
outside its stated range (`RANGES`: the ranges the Magic Formula states for its factors,
e.g. the shape factors $C > 0$, and the file's own ranges:
``FZMIN <= FNOMIN <= FZMAX``, ``PRESMIN <= INFLPRES, NOMPRES <= PRESMAX``, ``FZMIN >= 0``,
each minimum at most its maximum, and below it for the load, slip ratio and slip angle:
the ranges the curves are fitted and shown on). Keys this module does not know are kept, written back, and listed in
`TirFile.unknown_keys`.
"""

from __future__ import annotations

import dataclasses
import math
import os
import re
from collections.abc import Iterator
from pathlib import Path


__all__ = ["TirError", "TirEntry", "TirSection", "TirFile", "parse_tir", "read_tir",
           "format_tir", "write_tir", "shipped_tires"]


class TirError(ValueError):
    """A tyre property file that cannot be used, with the file, line and key at fault."""

    def __init__(self, source: str, line: int | None, key: str | None, message: str):
        self.source, self.line, self.key = source, line, key
        where = source if line is None else f"{source}:{line}"
        super().__init__(f"{where}: {key}: {message}" if key else f"{where}: {message}")


# --- what the module knows -----------------------------------------------------------------

# Section -> keys of the MF 5.2 / 6.1 / 6.2 property files (MF-Tyre/MF-Swift 6.1 and 6.2
# equation manuals; MSC Adams PAC2002). Turn-slip, vertical, contact and structural keys
# are kept and converted but not used by the steady-state formulas.
KNOWN_KEYS: dict[str, tuple[str, ...]] = {
    "MDI_HEADER": ("FILE_TYPE", "FILE_VERSION", "FILE_FORMAT"),
    "UNITS": ("LENGTH", "FORCE", "ANGLE", "MASS", "TIME", "PRESSURE"),
    "MODEL": ("PROPERTY_FILE_FORMAT", "FITTYP", "TYRESIDE", "LONGVL", "VXLOW",
              "ROAD_INCREMENT", "ROAD_DIRECTION", "USE_MODE", "USER_SUB_ID",
              "N_TIRE_STATES", "HMAX_LOCAL", "TIME_SWITCH_INTEG", "FUNCTION_NAME", "TYPE",
              "MFSAFE1", "MFSAFE2", "MFSAFE3", "FE_METHOD", "CONTACT_MODEL"),
    "DIMENSION": ("UNLOADED_RADIUS", "WIDTH", "ASPECT_RATIO", "RIM_RADIUS", "RIM_WIDTH"),
    "OPERATING_CONDITIONS": ("INFLPRES", "NOMPRES"),
    "INERTIA": ("MASS", "IXX", "IYY", "BELT_MASS", "BELT_IXX", "BELT_IYY", "GRAVITY"),
    "VERTICAL": ("FNOMIN", "VERTICAL_STIFFNESS", "VERTICAL_DAMPING", "MC_CONTOUR_A",
                 "MC_CONTOUR_B", "BREFF", "DREFF", "FREFF", "Q_RE0", "Q_V1", "Q_V2",
                 "Q_FZ2", "Q_FCX", "Q_FCY", "Q_CAM", "PFZ1", "Q_FCY2", "Q_CAM1", "Q_CAM2",
                 "Q_CAM3", "Q_FYS1", "Q_FYS2", "Q_FYS3", "BOTTOM_OFFST", "BOTTOM_STIFF"),
    "STRUCTURAL": ("LONGITUDINAL_STIFFNESS", "LATERAL_STIFFNESS", "YAW_STIFFNESS",
                   "FREQ_LONG", "FREQ_LAT", "FREQ_YAW", "FREQ_WINDUP", "DAMP_LONG",
                   "DAMP_LAT", "DAMP_YAW", "DAMP_WINDUP", "DAMP_RESIDUAL", "DAMP_VLOW",
                   "Q_BVX", "Q_BVT", "PCFX1", "PCFX2", "PCFX3", "PCFY1", "PCFY2", "PCFY3",
                   "PCMZ1"),
    "CONTACT_PATCH": ("Q_RA1", "Q_RA2", "Q_RB1", "Q_RB2", "ELLIPS_SHIFT", "ELLIPS_LENGTH",
                      "ELLIPS_HEIGHT", "ELLIPS_ORDER", "ELLIPS_MAX_STEP", "ELLIPS_NWIDTH",
                      "ELLIPS_NLENGTH", "ENV_C1", "ENV_C2", "Q_A1", "Q_A2"),
    "INFLATION_PRESSURE_RANGE": ("PRESMIN", "PRESMAX"),
    "VERTICAL_FORCE_RANGE": ("FZMIN", "FZMAX"),
    "LONG_SLIP_RANGE": ("KPUMIN", "KPUMAX"),
    "SLIP_ANGLE_RANGE": ("ALPMIN", "ALPMAX"),
    "INCLINATION_ANGLE_RANGE": ("CAMMIN", "CAMMAX"),
    "SCALING_COEFFICIENTS": ("LFZO", "LCX", "LMUX", "LEX", "LKX", "LHX", "LVX", "LGAX",
                             "LCY", "LMUY", "LEY", "LKY", "LHY", "LVY", "LGAY", "LKYC",
                             "LKZC", "LTR", "LRES", "LGAZ", "LXAL", "LYKA", "LVYKA", "LS",
                             "LSGKP", "LSGAL", "LGYR", "LMX", "LVMX", "LMY", "LMP", "LMUV",
                             "LCZ"),
    "LONGITUDINAL_COEFFICIENTS": ("PCX1", "PDX1", "PDX2", "PDX3", "PEX1", "PEX2", "PEX3",
                                  "PEX4", "PKX1", "PKX2", "PKX3", "PHX1", "PHX2", "PVX1",
                                  "PVX2", "PPX1", "PPX2", "PPX3", "PPX4", "RBX1", "RBX2",
                                  "RBX3", "RCX1", "REX1", "REX2", "RHX1", "PTX1", "PTX2",
                                  "PTX3"),
    "OVERTURNING_COEFFICIENTS": ("QSX1", "QSX2", "QSX3", "QSX4", "QSX5", "QSX6", "QSX7",
                                 "QSX8", "QSX9", "QSX10", "QSX11", "QSX12", "QSX13",
                                 "QSX14", "PPMX1"),
    "LATERAL_COEFFICIENTS": ("PCY1", "PDY1", "PDY2", "PDY3", "PEY1", "PEY2", "PEY3", "PEY4",
                             "PEY5", "PKY1", "PKY2", "PKY3", "PKY4", "PKY5", "PKY6", "PKY7",
                             "PHY1", "PHY2", "PHY3", "PVY1", "PVY2", "PVY3", "PVY4", "PPY1",
                             "PPY2", "PPY3", "PPY4", "PPY5", "RBY1", "RBY2", "RBY3", "RBY4",
                             "RCY1", "REY1", "REY2", "RHY1", "RHY2", "RVY1", "RVY2", "RVY3",
                             "RVY4", "RVY5", "RVY6", "PTY1", "PTY2"),
    "ROLLING_COEFFICIENTS": ("QSY1", "QSY2", "QSY3", "QSY4", "QSY5", "QSY6", "QSY7",
                             "QSY8"),
    "ALIGNING_COEFFICIENTS": ("QBZ1", "QBZ2", "QBZ3", "QBZ4", "QBZ5", "QBZ6", "QBZ9",
                              "QBZ10", "QCZ1", "QDZ1", "QDZ2", "QDZ3", "QDZ4", "QDZ6",
                              "QDZ7", "QDZ8", "QDZ9", "QDZ10", "QDZ11", "QEZ1", "QEZ2",
                              "QEZ3", "QEZ4", "QEZ5", "QHZ1", "QHZ2", "QHZ3", "QHZ4",
                              "PPZ1", "PPZ2", "SSZ1", "SSZ2", "SSZ3", "SSZ4", "QTZ1",
                              "MBELT"),
    "TURNSLIP_COEFFICIENTS": ("PDXP1", "PDXP2", "PDXP3", "PKYP1", "PDYP1", "PDYP2", "PDYP3",
                              "PDYP4", "PHYP1", "PHYP2", "PHYP3", "PHYP4", "PECP1", "PECP2",
                              "QDTP1", "QCRP1", "QCRP2", "QBRP1", "QDRP1"),
}
# sections that hold rows (tables) rather than keys
TABLE_SECTIONS = ("SHAPE", "DEFLECTION_LOAD_CURVE", "BOTTOMING_CURVE")

# Keys that the steady-state formulas cannot do without (a missing one is refused); every
# other coefficient takes its neutral value (0, scaling factors 1, PKY4 = 2) when absent.
REQUIRED: dict[str, tuple[str, ...]] = {
    "5.2": ("FNOMIN", "UNLOADED_RADIUS", "PCX1", "PDX1", "PKX1", "PCY1", "PDY1", "PKY1",
            "PKY2", "QCZ1"),
    "6.1": ("FNOMIN", "UNLOADED_RADIUS", "NOMPRES", "PCX1", "PDX1", "PKX1", "PCY1", "PDY1",
            "PKY1", "PKY2", "QCZ1"),
}
REQUIRED["6.2"] = REQUIRED["6.1"]

# Stated ranges: key -> (lower, upper, lower_open, upper_open, what states it). The shape
# factors are positive (Pacejka 2012, 4.E11, 4.E21, 4.E41: "(> 0)"), so are the nominal
# load, radius, pressure, the speeds, the load scaling and the longitudinal friction PDX1
# (the lateral PDY1 is not: its sign follows the file's axes).
RANGES: dict[str, tuple[float, float, bool, bool, str]] = {
    "FNOMIN": (0.0, math.inf, True, False, "the nominal load is positive"),
    "FZMIN": (0.0, math.inf, False, False, "a wheel load is not negative"),
    "UNLOADED_RADIUS": (0.0, math.inf, True, False, "the free radius is positive"),
    "NOMPRES": (0.0, math.inf, True, False, "the nominal pressure is positive"),
    "INFLPRES": (0.0, math.inf, True, False, "the inflation pressure is positive"),
    "LONGVL": (0.0, math.inf, True, False, "the reference speed is positive"),
    "VXLOW": (0.0, math.inf, True, False, "the low-speed threshold is positive"),
    "LFZO": (0.0, math.inf, True, False, "the load scaling factor is positive"),
    "PCX1": (0.0, math.inf, True, False, "C_x > 0 (4.E11)"),
    "PDX1": (0.0, math.inf, True, False, "the longitudinal friction at the nominal load, "
                                         "mu_x of 4.E13, is positive: D_x = mu_x F_z (4.E12)"),
    "PCY1": (0.0, math.inf, True, False, "C_y > 0 (4.E21)"),
    "QCZ1": (0.0, math.inf, True, False, "C_t > 0 (4.E41)"),
    "PKY2": (0.0, math.inf, True, False, "the load of peak cornering stiffness is positive "
                                         "(4.E25)"),
}
# pairs (low, high) that must be ordered, and values that must lie between them
ORDERED_PAIRS = (("FZMIN", "FZMAX"), ("PRESMIN", "PRESMAX"), ("KPUMIN", "KPUMAX"),
                 ("ALPMIN", "ALPMAX"), ("CAMMIN", "CAMMAX"))
# the pairs that span the curves fitted and shown, so must have a width; a file measured
# at one pressure or one camber may give that value as both ends of its range
STRICT_PAIRS = (("FZMIN", "FZMAX"), ("KPUMIN", "KPUMAX"), ("ALPMIN", "ALPMAX"))
WITHIN = (("FNOMIN", "FZMIN", "FZMAX"), ("NOMPRES", "PRESMIN", "PRESMAX"),
          ("INFLPRES", "PRESMIN", "PRESMAX"))

# Units: name (lower case) -> factor to SI.
UNITS: dict[str, dict[str, float]] = {
    "LENGTH": {"meter": 1.0, "metre": 1.0, "m": 1.0, "mm": 1e-3, "millimeter": 1e-3,
               "millimetre": 1e-3, "cm": 1e-2, "centimeter": 1e-2, "km": 1e3,
               "kilometer": 1e3, "inch": 0.0254, "in": 0.0254, "foot": 0.3048, "ft": 0.3048},
    "FORCE": {"newton": 1.0, "n": 1.0, "kn": 1e3, "kilonewton": 1e3,
              "pound_force": 4.4482216152605, "lbf": 4.4482216152605,
              "kg_force": 9.80665, "kgf": 9.80665},
    "ANGLE": {"radian": 1.0, "radians": 1.0, "rad": 1.0, "degree": math.pi / 180,
              "degrees": math.pi / 180, "deg": math.pi / 180},
    "MASS": {"kg": 1.0, "kilogram": 1.0, "gram": 1e-3, "g": 1e-3, "tonne": 1e3,
             "pound_mass": 0.45359237, "lbm": 0.45359237, "slug": 14.59390294},
    "TIME": {"second": 1.0, "sec": 1.0, "s": 1.0, "millisecond": 1e-3, "ms": 1e-3,
             "minute": 60.0, "min": 60.0, "hour": 3600.0},
    "PRESSURE": {"pascal": 1.0, "pa": 1.0, "kpa": 1e3, "kilopascal": 1e3, "mpa": 1e6,
                 "bar": 1e5, "psi": 6894.757293168, "atm": 101325.0},
}
# Dimension of each dimensional key as exponents of (length, force, angle, mass, time);
# pressure is its own unit when [UNITS] names one, force / length^2 otherwise.
_L, _F, _A, _M, _T = range(5)
_DIMS: dict[str, tuple[int, int, int, int, int] | str] = {}
for _k in ("UNLOADED_RADIUS", "WIDTH", "RIM_RADIUS", "RIM_WIDTH", "BOTTOM_OFFST",
           "ELLIPS_MAX_STEP", "ROAD_INCREMENT"):
    _DIMS[_k] = (1, 0, 0, 0, 0)
for _k in ("FNOMIN", "FZMIN", "FZMAX"):
    _DIMS[_k] = (0, 1, 0, 0, 0)
for _k in ("VERTICAL_STIFFNESS", "BOTTOM_STIFF", "LONGITUDINAL_STIFFNESS",
           "LATERAL_STIFFNESS"):
    _DIMS[_k] = (-1, 1, 0, 0, 0)
_DIMS["VERTICAL_DAMPING"] = (-1, 1, 0, 0, 1)
_DIMS["YAW_STIFFNESS"] = (1, 1, -1, 0, 0)
for _k in ("LONGVL", "VXLOW"):
    _DIMS[_k] = (1, 0, 0, 0, -1)
for _k in ("INFLPRES", "NOMPRES", "PRESMIN", "PRESMAX"):
    _DIMS[_k] = "pressure"
for _k in ("ALPMIN", "ALPMAX", "CAMMIN", "CAMMAX"):
    _DIMS[_k] = (0, 0, 1, 0, 0)
for _k in ("MASS", "BELT_MASS", "MBELT"):
    _DIMS[_k] = (0, 0, 0, 1, 0)
for _k in ("IXX", "IYY", "BELT_IXX", "BELT_IYY"):
    _DIMS[_k] = (2, 0, 0, 1, 0)
_DIMS["GRAVITY"] = (1, 0, 0, 0, -2)
for _k in ("FREQ_LONG", "FREQ_LAT", "FREQ_YAW", "FREQ_WINDUP"):
    _DIMS[_k] = (0, 0, 0, 0, -1)
for _k in ("HMAX_LOCAL", "TIME_SWITCH_INTEG"):
    _DIMS[_k] = (0, 0, 0, 0, 1)

_NUMERIC = set(_DIMS) | {k for pair in ORDERED_PAIRS for k in pair} | {
    k for triple in WITHIN for k in triple}
"""Keys whose value must be a number: the dimensional ones and those of the stated ranges
(the slip ratio's ``KPUMIN``/``KPUMAX`` among them), besides every key of a section whose
name ends in ``_COEFFICIENTS`` (the formulas' coefficients and scaling factors)."""

_VERSIONS = {5: "5.2", 6: "5.2", 21: "5.2", 52: "5.2", 61: "6.1", 62: "6.2"}


# --- the data ------------------------------------------------------------------------------

Value = float | int | str | None


@dataclasses.dataclass(frozen=True)
class TirEntry:
    """One ``KEY = value`` line: the key as written, its value (a number, a string, or
    None when empty), the comment after it, its line number and the line as written."""

    key: str
    value: Value
    comment: str
    line: int
    text: str


@dataclasses.dataclass(frozen=True)
class TirSection:
    """A ``[NAME]`` section: its header line and its items in order, each a `TirEntry` or
    a line kept as written (comments, blank lines, table rows)."""

    name: str
    line: int
    header: str
    items: tuple[TirEntry | str, ...]

    @property
    def entries(self) -> dict[str, TirEntry]:
        """Upper-cased key -> entry."""
        return {it.key.upper(): it for it in self.items if isinstance(it, TirEntry)}

    @property
    def rows(self) -> tuple[str, ...]:
        """The lines that are not keys, comments or blank (a table section's rows)."""
        return tuple(it for it in self.items if isinstance(it, str) and it.strip()
                     and not _is_comment(it))


@dataclasses.dataclass(frozen=True)
class TirFile:
    """A parsed tyre property file (module docstring). Build with `parse_tir`/`read_tir`.

    - `source`: where it came from (for messages); `preamble`: the lines before the first
      section; `sections`: the sections in file order (a table section may appear twice,
      as in some real files); `trailing_newline`.

    Keys are looked up in every section but ``[UNITS]`` (whose ``MASS`` names a unit, not
    the tyre's mass: see `units`).
    """

    source: str
    preamble: tuple[str, ...]
    sections: tuple[TirSection, ...]
    trailing_newline: bool = True

    def section(self, name: str) -> TirSection | None:
        """The first section called `name` (upper case), or None."""
        return next((s for s in self.sections if s.name == name.upper()), None)

    # -- looking things up
    def _find(self, key: str) -> TirEntry | None:
        key = key.upper()
        for sec in self.sections:
            if sec.name == "UNITS":
                continue
            e = sec.entries.get(key)
            if e is not None:
                return e
        return None

    def __contains__(self, key: str) -> bool:
        e = self._find(key)
        return e is not None and e.value is not None

    def entry(self, key: str) -> TirEntry | None:
        """The entry of `key` (any section), or None."""
        return self._find(key)

    def raw(self, key: str, default: Value = None) -> Value:
        """The value of `key` as written (no unit conversion), or `default`."""
        e = self._find(key)
        return default if e is None or e.value is None else e.value

    def get(self, key: str, default: Value = None) -> Value:
        """The value of `key` in SI units (module docstring), or `default`."""
        e = self._find(key)
        if e is None or e.value is None:
            return default
        if isinstance(e.value, str):
            return e.value
        return float(e.value) * self.unit_factor(key)

    def entries(self) -> Iterator[tuple[str, TirEntry]]:
        """(section name, entry) for every key, in file order."""
        for sec in self.sections:
            for it in sec.items:
                if isinstance(it, TirEntry):
                    yield sec.name, it

    # -- units and version
    @property
    def units(self) -> dict[str, str]:
        """[UNITS] as written (lower case), SI where a unit is not named."""
        sec = self.section("UNITS")
        out = {"LENGTH": "meter", "FORCE": "newton", "ANGLE": "radian", "MASS": "kg",
               "TIME": "second"}
        if sec is not None:
            for k, e in sec.entries.items():
                if isinstance(e.value, str):
                    out[k] = e.value.strip().lower()
        return out

    def unit_factor(self, key: str) -> float:
        """The factor that converts `key`'s value to SI (1 for dimensionless keys)."""
        dims = _DIMS.get(key.upper())
        if dims is None:
            return 1.0
        u = self.units
        factor = {q: UNITS[q][u[q]] for q in ("LENGTH", "FORCE", "ANGLE", "MASS", "TIME")}
        if dims == "pressure":
            if "PRESSURE" in u:
                return UNITS["PRESSURE"][u["PRESSURE"]]
            return factor["FORCE"] / factor["LENGTH"] ** 2
        out = 1.0
        for q, n in zip(("LENGTH", "FORCE", "ANGLE", "MASS", "TIME"), dims):
            out *= factor[q] ** n
        return out

    def si(self) -> dict[str, float]:
        """Every numeric key (upper case) -> its value in SI units."""
        return {e.key.upper(): self.get(e.key) for name, e in self.entries()
                if name != "UNITS" and isinstance(e.value, int | float)}

    @property
    def version(self) -> str:
        """``"5.2"``, ``"6.1"`` or ``"6.2"`` (module docstring)."""
        return _version(self)

    @property
    def unknown_keys(self) -> list[tuple[str, str, int]]:
        """(section, key, line) of every key this module does not know (kept as written)."""
        known = {s: set(keys) for s, keys in KNOWN_KEYS.items()}
        return [(name, e.key, e.line) for name, e in self.entries()
                if e.key.upper() not in known.get(name.upper(), ())]

    # -- changing values
    def replace(self, **values: Value) -> TirFile:
        """A copy with the named keys set (in the units of the file): every entry of a key
        outside ``[UNITS]`` is changed, and a key not present is appended to the section
        `KNOWN_KEYS` puts it in (``[INERTIA]`` for ``MASS``; created at the end if needed).

        A value is a number, a string on one line, or None (present but empty). The copy is
        read again from its text, so its line numbers are those of the written file and a
        value outside its range raises `read_tir`'s `TirError`.
        """
        for key, value in values.items():
            if not _KEY_NAME.fullmatch(key):
                raise ValueError(f"TirFile.replace: {key!r} is not a key name (letters, "
                                 "digits and _, not starting with a digit)")
            if isinstance(value, bool) or not isinstance(value, int | float | str | None):
                raise TypeError(f"TirFile.replace: {key} must be a number, a string or None, "
                                f"got {type(value).__name__}")
            if isinstance(value, float) and not math.isfinite(value):
                raise ValueError(f"TirFile.replace: {key} must be finite, got {value}")
            if isinstance(value, str) and re.search(r"[\r\n]", value):
                raise ValueError(f"TirFile.replace: {key}'s string {value!r} holds a line "
                                 "break")
        sections = list(self.sections)
        for key, value in values.items():
            key_u = key.upper()
            found = False
            for i, sec in enumerate(sections):
                e = sec.entries.get(key_u)
                if e is not None and sec.name != "UNITS":
                    sections[i] = _replace_entry(sec, e, value)
                    found = True
            if not found:
                home = next((s for s, keys in KNOWN_KEYS.items()
                             if key_u in keys and s != "UNITS"), "USER")
                new = TirEntry(key_u, value, "", 0, _entry_line(key_u, value, ""))
                i = next((i for i, s in enumerate(sections) if s.name == home), None)
                if i is None:
                    sections.append(TirSection(home, 0, f"[{home}]", (new,)))
                else:
                    sections[i] = dataclasses.replace(sections[i],
                                                      items=sections[i].items + (new,))
        changed = dataclasses.replace(self, sections=tuple(sections))
        return parse_tir(format_tir(changed), source=self.source)


def _replace_entry(sec: TirSection, e: TirEntry, value: Value) -> TirSection:
    new = dataclasses.replace(e, value=value, text=_entry_line(e.key, value, e.comment))
    return dataclasses.replace(sec, items=tuple(new if it is e else it for it in sec.items))


# --- parsing -------------------------------------------------------------------------------

_SECTION = re.compile(r"^\s*\[\s*([A-Za-z0-9_ ]+?)\s*\]\s*(?:[$!].*)?$")
_KEY_NAME = re.compile(r"[A-Za-z_][A-Za-z0-9_]*")
_KEY = re.compile(rf"^\s*({_KEY_NAME.pattern})\s*=\s*(.*)$")
_NUMBER = re.compile(r"^[+-]?(\d+\.?\d*|\.\d+)([eEdD][+-]?\d+)?$")


def _is_comment(line: str) -> bool:
    s = line.lstrip()
    return s.startswith("$") or s.startswith("!")


def _split_value(rest: str) -> tuple[str, str]:
    """(value text, comment) of what follows ``=``; comments start at ``$``/``!`` outside
    quotes."""
    quote = None
    for i, ch in enumerate(rest):
        if quote:
            if ch == quote:
                quote = None
        elif ch in "'\"":
            quote = ch
        elif ch in "$!":
            return rest[:i].strip(), rest[i:].rstrip()
    return rest.strip(), ""


def _value(text: str) -> Value:
    """The value a value text denotes; raises ValueError for anything else."""
    if text == "":
        return None
    if len(text) >= 2 and text[0] == text[-1] and text[0] in "'\"":
        return text[1:-1]
    if _NUMBER.match(text):
        t = text.replace("d", "e").replace("D", "e")
        v = float(t)
        if re.fullmatch(r"[+-]?\d+", t) and math.isfinite(v):
            return int(t)
        if not math.isfinite(v):  # beyond the double range: 1e400 reads as inf
            raise ValueError(f"the number {text!r} is not finite in double precision")
        return v
    raise ValueError(f"cannot read the value {text!r} (a number, a quoted string or "
                     "nothing)")


def parse_tir(text: str, source: str = "<text>") -> TirFile:
    """Parse the text of a tyre property file (module docstring); raise `TirError` naming
    `source`, the line and the key of the first problem found (a `TypeError` for `text` that
    is not a string: `read_tir` reads a file)."""
    if not isinstance(text, str):
        raise TypeError(f"parse_tir needs the file's text (a str; read_tir reads a path), got "
                        f"{type(text).__name__}")
    # lines end at \n, \r\n or \r only (str.splitlines also splits at \x85, \x0b,
    # \x0c and \x1c-\x1e, which a latin-1 file may hold in a comment); a leading byte
    # order mark (an editor's UTF-8) is not text
    lines = re.split(r"\r\n|\r|\n", text.removeprefix("\ufeff").removeprefix("\xef\xbb\xbf"))
    if lines[-1] == "":  # the file's last newline ends its last line
        lines.pop()
    preamble: list[str] = []
    sections: list[TirSection] = []
    current: tuple[str, int, str, list] | None = None
    seen: dict[tuple[str, str], int] = {}  # (section, KEY) -> line
    values: dict[str, tuple] = {}  # KEY -> (section, line, value, text) where first given

    def close():
        if current is not None:
            name, line, header, items = current
            sections.append(TirSection(name, line, header, tuple(items)))

    for n, raw in enumerate(lines, start=1):
        m = _SECTION.match(raw)
        if m:
            close()
            name = re.sub(r"\s+", "_", m.group(1).strip()).upper()
            units_line = next((s.line for s in sections if s.name == "UNITS"), None)
            if name == "UNITS" and units_line is not None:
                raise TirError(source, n, None, f"a second [UNITS] section (the first is on "
                               f"line {units_line}): one set of units applies to the whole file")
            current = (name, n, raw, [])
            continue
        if not raw.strip() or _is_comment(raw):
            (preamble if current is None else current[3]).append(raw)
            continue
        if current is None:
            raise TirError(source, n, None, f"text before the first section: {raw.strip()!r}")
        name, _, _, items = current
        km = _KEY.match(raw)
        if km:
            key = km.group(1)
            value_text, comment = _split_value(km.group(2))
            try:
                value = _value(value_text)
            except ValueError as err:
                raise TirError(source, n, key, str(err)) from None
            if (name, key.upper()) in seen:
                raise TirError(source, n, key, f"given twice in section [{name}] (first "
                                               f"on line {seen[name, key.upper()]})")
            seen[name, key.upper()] = n
            first = values.get(key.upper())
            if name != "UNITS" and first is not None and first[2] != value:
                raise TirError(source, n, key,
                               f"{value_text or 'empty'} here, in [{name}], but "
                               f"{first[3] or 'empty'} in [{first[0]}] on line {first[1]}: "
                               "a key given in two sections must have one value")
            if name != "UNITS" and first is None:
                values[key.upper()] = (name, n, value, value_text)
            items.append(TirEntry(key, value, comment, n, raw))
            continue
        if name in TABLE_SECTIONS or _is_row(raw):
            items.append(raw)  # a table row or a table header such as {radial width}
            continue
        raise TirError(source, n, None, f"cannot read this line of section [{name}]: "
                                        f"{raw.strip()!r} (expected KEY = value)")
    close()
    tir = TirFile(source, tuple(preamble), tuple(sections), text.endswith(("\n", "\r")))
    validate(tir)
    return tir


def _is_row(line: str) -> bool:
    s = line.strip()
    if s.startswith("{") and s.endswith("}"):
        return True
    return all(_NUMBER.match(tok) for tok in s.split())


def _version(tir: TirFile) -> str:
    e = tir.entry("FITTYP")
    if e is not None and e.value is not None:
        if (not isinstance(e.value, int | float) or not math.isfinite(e.value)
                or e.value != int(e.value) or int(e.value) not in _VERSIONS):
            raise TirError(tir.source, e.line, "FITTYP",
                           f"unknown Magic Formula version {e.value!r} (known: 5, 6, 21, "
                           "52 for MF 5.2/PAC2002, 61 for MF 6.1, 62 for MF 6.2)")
        return _VERSIONS[int(e.value)]
    e = tir.entry("PROPERTY_FILE_FORMAT")
    if e is not None and isinstance(e.value, str) and e.value.strip().upper() == "PAC2002":
        return "5.2"
    line = None if e is None else e.line
    raise TirError(tir.source, line, "PROPERTY_FILE_FORMAT" if e else "FITTYP",
                   "cannot tell the Magic Formula version: no FITTYP, and "
                   f"PROPERTY_FILE_FORMAT is {None if e is None else e.value!r} (only "
                   "'PAC2002' names a version)")


def validate(tir: TirFile) -> None:
    """Raise `TirError` for an unknown unit or version, a missing required key or a value
    outside its stated range (module docstring)."""
    units = tir.section("UNITS")
    if units is not None:
        for key, e in units.entries.items():
            if key in UNITS and (not isinstance(e.value, str)
                                 or e.value.strip().lower() not in UNITS[key]):
                raise TirError(tir.source, e.line, e.key,
                               f"unknown unit {e.value!r} (known: "
                               f"{', '.join(sorted(UNITS[key]))})")
    version = _version(tir)
    for key in REQUIRED[version]:
        if key not in tir:
            e = tir.entry(key)
            raise TirError(tir.source, None if e is None else e.line, key,
                           f"required by the MF {version} formulas but "
                           f"{'empty' if e is not None else 'missing'}")
    for name, e in tir.entries():
        if name != "UNITS" and isinstance(e.value, str) and (
                e.key.upper() in _NUMERIC or name.upper().endswith("_COEFFICIENTS")):
            raise TirError(tir.source, e.line, e.key, f"must be a number, got {e.value!r}")
    for key, (lo, hi, lo_open, hi_open, why) in RANGES.items():
        e = tir.entry(key)
        if e is None or e.value is None:
            continue
        if not isinstance(e.value, int | float):
            raise TirError(tir.source, e.line, e.key, f"must be a number, got {e.value!r}")
        v = float(e.value)
        ok = (v > lo if lo_open else v >= lo) and (v < hi if hi_open else v <= hi)
        if not ok or not math.isfinite(v):
            lb = "(" if lo_open or lo == -math.inf else "["
            ub = ")" if hi_open or hi == math.inf else "]"
            raise TirError(tir.source, e.line, e.key,
                           f"{e.value} is outside its stated range {lb}{lo:g}, {hi:g}{ub} "
                           f"({why})")
    for lo_key, hi_key in ORDERED_PAIRS:
        lo, hi = tir.get(lo_key), tir.get(hi_key)
        if lo is None or hi is None:
            continue
        e = tir.entry(hi_key)
        if not lo <= hi:
            raise TirError(tir.source, e.line, hi_key,
                           f"{tir.raw(hi_key)} is below {lo_key} = {tir.raw(lo_key)}")
        if lo == hi and (lo_key, hi_key) in STRICT_PAIRS:
            raise TirError(tir.source, e.line, hi_key,
                           f"{tir.raw(hi_key)} equals {lo_key}: the range the curves are "
                           "fitted and shown on has no width (its minimum must be below "
                           "its maximum)")
    for key, lo_key, hi_key in WITHIN:
        v, lo, hi = tir.get(key), tir.get(lo_key), tir.get(hi_key)
        if v is None:
            continue
        if (lo is not None and v < lo) or (hi is not None and v > hi):
            e = tir.entry(key)
            raise TirError(tir.source, e.line, key,
                           f"{tir.raw(key)} is outside the file's stated range "
                           f"[{lo_key}, {hi_key}] = [{tir.raw(lo_key)}, {tir.raw(hi_key)}]")


# --- writing -------------------------------------------------------------------------------

def _format_value(value: Value) -> str:
    if value is None:
        return ""
    if isinstance(value, str):
        return f"'{value}'"
    if isinstance(value, bool):
        raise TypeError("a .tir value is a number, a string or None")
    if isinstance(value, int):
        return str(value)
    return repr(float(value))


def _entry_line(key: str, value: Value, comment: str) -> str:
    line = f"{key:<24} = {_format_value(value)}"
    return f"{line:<44} {comment}" if comment else line


def format_tir(tir: TirFile) -> str:
    """The text of `tir`: the lines as read, with each changed value written anew."""
    out = list(tir.preamble)
    for sec in tir.sections:
        out.append(sec.header)
        out.extend(it.text if isinstance(it, TirEntry) else it for it in sec.items)
    return "\n".join(out) + ("\n" if tir.trailing_newline else "")


# --- the disk ------------------------------------------------------------------------------

def read_tir(path: str | os.PathLike) -> TirFile:
    """`parse_tir` of the file at `path` (messages name the file)."""
    path = Path(path)
    data = path.read_bytes()
    if b"\x00" in data:
        raise TirError(str(path), None, None, "not a text file (it holds NUL bytes, as UTF-16 "
                       "or binary files do): save it as ASCII, latin-1 or UTF-8 text")
    return parse_tir(data.decode("latin-1"), source=str(path))


def write_tir(path: str | os.PathLike, tir: TirFile) -> Path:
    """Write `format_tir(tir)` to `path` atomically (a temporary file, then a rename). A
    file that `read_tir` would refuse (a value outside its range, a required key missing)
    is refused first, with `read_tir`'s `TirError`, and nothing is written."""
    from .._checks import check_type
    from .._io import write_atomic

    check_type("write_tir", "tir", tir, TirFile)
    text = format_tir(tir)
    parse_tir(text, source=str(path))
    return write_atomic(path, text.encode("latin-1"))


def shipped_tires() -> dict[str, Path]:
    """The tyre property files shipped with vehsim: name -> path (their sources are in
    each file's header and in docs/parameters.md)."""
    folder = Path(__file__).resolve().parent.parent / "data" / "tires"
    return {p.stem: p for p in sorted(folder.glob("*.tir"))}
