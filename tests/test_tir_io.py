"""Tyre property files: reading, writing, units, versions, and every bad input refused with
the file, the line and the key. The tests write their own files to tmp_path; the shipped
sample is read as a file of the package."""

import difflib
import math

import numpy as np
import pytest

from vehsim.tire.mf6 import MFParams, mf_forces
from vehsim.tire.tir import (
    TirError,
    format_tir,
    parse_tir,
    read_tir,
    shipped_tires,
    write_tir,
)


SAMPLE = shipped_tires()["sample_185_80R14_mf61"]

SMALL = """\
! a small MF 6.1 file written by the tests
$------------------------------------------------units
[UNITS]
LENGTH                   = 'meter'
FORCE                    = 'newton'
ANGLE                    = 'radians'
MASS                     = 'kg'
TIME                     = 'second'
[MODEL]
FITTYP                   = 61                 $Magic Formula version number
TYRESIDE                 = 'LEFT'
FOO_SWITCH               = 3                  ! a key vehsim does not know
LONGVL                   = 16.7
[DIMENSION]
UNLOADED_RADIUS          = 0.3135
WIDTH                    =
[SHAPE]
{radial width}
 1.0    0.0
 0.9    1.0
[OPERATING_CONDITIONS]
INFLPRES                 = 2.2D+5
NOMPRES                  = 220000
[VERTICAL]
FNOMIN                   = 4000
VERTICAL_STIFFNESS       = 2.0e5
[VERTICAL_FORCE_RANGE]
FZMIN                    = 100
FZMAX                    = 10000
[INFLATION_PRESSURE_RANGE]
PRESMIN                  = 150000
PRESMAX                  = 300000
[SLIP_ANGLE_RANGE]
ALPMIN                   = -0.5
ALPMAX                   = 0.5
[LONGITUDINAL_COEFFICIENTS]
PCX1                     = 1.6
PDX1                     = 1.1
PKX1                     = 20.0
[LATERAL_COEFFICIENTS]
PCY1                     = 1.4
PDY1                     = 0.95
PKY1                     = -15.0
PKY2                     = 1.7
[ALIGNING_COEFFICIENTS]
QCZ1                     = 1.1
QBZ1                     = 9.0
QDZ1                     = 0.1
"""


def test_the_text_round_trips_byte_for_byte_and_through_the_disk(tmp_path):
    tir = parse_tir(SMALL)
    assert format_tir(tir) == SMALL
    path = write_tir(tmp_path / "a.tir", tir)
    again = read_tir(path)
    assert again.sections == tir.sections and path.read_text() == SMALL
    sample = SAMPLE.read_text()
    assert format_tir(parse_tir(sample)) == sample


def test_values_comments_strings_tables_and_empty_values_are_read():
    tir = parse_tir(SMALL)
    assert tir.version == "6.1"
    assert tir.raw("TYRESIDE") == "LEFT" and tir.raw("FITTYP") == 61
    assert tir.raw("INFLPRES") == 2.2e5  # Fortran exponent
    assert tir.entry("FITTYP").comment == "$Magic Formula version number"
    assert tir.entry("WIDTH").value is None and "WIDTH" not in tir  # present but empty
    assert tir.section("SHAPE").rows == ("{radial width}", " 1.0    0.0", " 0.9    1.0")
    assert [s.name for s in tir.sections][:3] == ["UNITS", "MODEL", "DIMENSION"]
    assert tir.preamble[0] == "! a small MF 6.1 file written by the tests"


def test_unknown_keys_are_kept_reported_and_written_back(tmp_path):
    tir = parse_tir(SMALL)
    assert tir.unknown_keys == [("MODEL", "FOO_SWITCH", 12)]
    assert tir.raw("FOO_SWITCH") == 3
    assert "FOO_SWITCH               = 3" in format_tir(tir)


def test_a_changed_value_is_written_in_the_layout_and_read_back(tmp_path):
    tir = parse_tir(SMALL).replace(PDY1=1.05, PEY1=-0.5)
    text = format_tir(tir)
    back = parse_tir(text)
    assert back.raw("PDY1") == 1.05 and back.raw("PEY1") == -0.5
    assert back.section("LATERAL_COEFFICIENTS").entries["PEY1"].line > 0
    # PDY1 changed in place, PEY1 appended to its section; the other lines are untouched
    diff = [d for d in difflib.ndiff(SMALL.splitlines(), text.splitlines())
            if d[:1] in "+-"]
    assert diff == ["- PDY1                     = 0.95", "+ PDY1                     = 1.05",
                    "+ PEY1                     = -0.5"]
    lateral = [e.key for e in back.section("LATERAL_COEFFICIENTS").entries.values()]
    assert lateral[-1] == "PEY1"


@pytest.mark.parametrize("fittyp,version", [(5, "5.2"), (6, "5.2"), (21, "5.2"), (52, "5.2"),
                                            (61, "6.1"), (62, "6.2")])
def test_fittyp_decides_the_version(fittyp, version):
    assert parse_tir(SMALL.replace("= 61 ", f"= {fittyp} ")).version == version


def test_property_file_format_pac2002_means_mf52():
    text = SMALL.replace("FITTYP                   = 61                 $Magic Formula "
                         "version number\n", "PROPERTY_FILE_FORMAT = 'PAC2002'\n")
    assert parse_tir(text).version == "5.2"


def test_units_are_converted_to_si_and_the_coefficients_kept():
    mm = (SMALL.replace("'meter'", "'mm'").replace("'newton'", "'kN'")
          .replace("'radians'", "'degrees'")
          .replace("UNLOADED_RADIUS          = 0.3135", "UNLOADED_RADIUS          = 313.5")
          .replace("FNOMIN                   = 4000", "FNOMIN                   = 4")
          .replace("FZMIN                    = 100", "FZMIN                    = 0.1")
          .replace("FZMAX                    = 10000", "FZMAX                    = 10")
          .replace("VERTICAL_STIFFNESS       = 2.0e5", "VERTICAL_STIFFNESS       = 0.2")
          .replace("LONGVL                   = 16.7", "LONGVL                   = 16700")
          .replace("ALPMIN                   = -0.5", "ALPMIN                   = -30")
          .replace("ALPMAX                   = 0.5", "ALPMAX                   = 30")
          .replace("INFLPRES                 = 2.2D+5", "INFLPRES                 = 2.2e-4")
          .replace("NOMPRES                  = 220000", "NOMPRES                  = 2.2e-4")
          .replace("PRESMIN                  = 150000", "PRESMIN                  = 1.5e-4")
          .replace("PRESMAX                  = 300000", "PRESMAX                  = 3.0e-4"))
    tir = parse_tir(mm)
    assert tir.units["LENGTH"] == "mm" and tir.raw("UNLOADED_RADIUS") == 313.5
    si = tir.si()
    assert si["UNLOADED_RADIUS"] == pytest.approx(0.3135)
    assert si["FNOMIN"] == pytest.approx(4000.0)
    assert si["VERTICAL_STIFFNESS"] == pytest.approx(2.0e5)  # kN/mm -> N/m
    assert si["LONGVL"] == pytest.approx(16.7)  # mm/s -> m/s
    assert si["ALPMAX"] == pytest.approx(math.radians(30))
    assert si["NOMPRES"] == pytest.approx(2.2e5)  # kN/mm^2 -> Pa
    assert si["PKY1"] == -15.0  # the Magic Formula coefficients are read as written
    # a pressure unit of its own
    bar = parse_tir(SMALL.replace("TIME                     = 'second'",
                                  "TIME                     = 'second'\n"
                                  "PRESSURE                 = 'bar'")
                    .replace("2.2D+5", "2.2").replace("= 220000", "= 2.2")
                    .replace("= 150000", "= 1.5").replace("= 300000", "= 3.0"))
    assert bar.get("NOMPRES") == pytest.approx(2.2e5)
    # the same tire in other units gives the same forces
    a, b = MFParams.from_tir(parse_tir(SMALL)), MFParams.from_tir(tir)
    kappa, alpha = np.array([0.0, 0.05, -0.1]), np.array([0.0, -0.05, 0.1])
    np.testing.assert_allclose(mf_forces(b, kappa, alpha, 3000.0),
                               mf_forces(a, kappa, alpha, 3000.0), rtol=1e-12, atol=1e-9)


def _refused(tmp_path, text, line, key, words):
    path = tmp_path / "bad.tir"
    path.write_text(text)
    with pytest.raises(TirError) as err:
        read_tir(path)
    message = str(err.value)
    where = f"{path}:{line}" if line is not None else str(path)
    assert message.startswith(where + ":"), message
    if key is not None:
        assert f": {key}:" in message and err.value.key == key, message
    assert err.value.line == line
    for word in words:
        assert word in message, message
    return message


def _line_of(text, start):
    return next(n for n, line in enumerate(text.splitlines(), 1) if line.startswith(start))


def test_a_line_that_is_no_key_is_refused(tmp_path):
    text = SMALL.replace("PKY2                     = 1.7", "PKY2 1.7")
    _refused(tmp_path, text, _line_of(text, "PKY2 1.7"), None, ["cannot read this line"])


def test_a_value_that_is_neither_number_nor_string_is_refused(tmp_path):
    text = SMALL.replace("PDY1                     = 0.95", "PDY1                     = 0.9.5")
    _refused(tmp_path, text, _line_of(text, "PDY1"), "PDY1", ["cannot read the value"])


def test_a_key_given_twice_is_refused(tmp_path):
    text = SMALL.replace("PKY2                     = 1.7", "PKY2 = 1.7\nPKY2 = 1.8")
    _refused(tmp_path, text, _line_of(text, "PKY2 = 1.8"), "PKY2", ["given twice"])


def test_an_unknown_unit_is_refused(tmp_path):
    text = SMALL.replace("'meter'", "'furlong'")
    _refused(tmp_path, text, _line_of(text, "LENGTH"), "LENGTH", ["unknown unit", "furlong"])


def test_an_unknown_formula_version_is_refused(tmp_path):
    text = SMALL.replace("= 61 ", "= 99 ")
    _refused(tmp_path, text, _line_of(text, "FITTYP"), "FITTYP", ["unknown Magic Formula "
                                                                   "version", "99"])
    text = SMALL.replace("FITTYP                   = 61", "PROPERTY_FILE_FORMAT = 'PAC89'")
    _refused(tmp_path, text, _line_of(text, "PROPERTY_FILE_FORMAT"), "PROPERTY_FILE_FORMAT",
             ["cannot tell the Magic Formula version", "PAC89"])


def test_a_missing_or_empty_required_coefficient_is_refused(tmp_path):
    text = SMALL.replace("PDY1                     = 0.95\n", "")
    _refused(tmp_path, text, None, "PDY1", ["required", "missing"])
    text = SMALL.replace("PDY1                     = 0.95", "PDY1                     =")
    _refused(tmp_path, text, _line_of(text, "PDY1"), "PDY1", ["required", "empty"])


def test_values_outside_their_stated_ranges_are_refused(tmp_path):
    text = SMALL.replace("PCY1                     = 1.4", "PCY1                     = -1.4")
    _refused(tmp_path, text, _line_of(text, "PCY1"), "PCY1", ["outside its stated range",
                                                               "(0, inf)", "4.E21"])
    text = SMALL.replace("FZMAX                    = 10000", "FZMAX                    = 50")
    _refused(tmp_path, text, _line_of(text, "FZMAX"), "FZMAX", ["below FZMIN"])
    for pdx1 in ("0", "-1.1"):  # no longitudinal grip, or a force against the slip
        text = SMALL.replace("PDX1                     = 1.1", f"PDX1 = {pdx1}")
        _refused(tmp_path, text, _line_of(text, "PDX1"), "PDX1", ["outside its stated range",
                                                                   "(0, inf)", "4.E13"])
    # a load range, slip ratio range or slip angle range with no width, a negative load;
    # a file measured at one pressure may give it as both ends of its range
    text = SMALL.replace("FZMAX                    = 10000", "FZMAX                    = 100")
    _refused(tmp_path, text, _line_of(text, "FZMAX"), "FZMAX", ["equals FZMIN", "no width"])
    text = SMALL.replace("ALPMAX                   = 0.5", "ALPMAX                   = -0.5")
    _refused(tmp_path, text, _line_of(text, "ALPMAX"), "ALPMAX", ["equals ALPMIN"])
    text = SMALL.replace("[SLIP_ANGLE_RANGE]", "[LONG_SLIP_RANGE]\nKPUMIN = 0.1\n"
                         "KPUMAX = 0.1\n[SLIP_ANGLE_RANGE]")
    _refused(tmp_path, text, _line_of(text, "KPUMAX"), "KPUMAX", ["equals KPUMIN"])
    text = SMALL.replace("FZMIN                    = 100", "FZMIN                    = -100")
    _refused(tmp_path, text, _line_of(text, "FZMIN"), "FZMIN", ["outside its stated range",
                                                                 "not negative"])
    path = tmp_path / "one_pressure.tir"
    path.write_text(SMALL.replace("PRESMIN                  = 150000",
                                  "PRESMIN                  = 220000")
                    .replace("PRESMAX                  = 300000",
                             "PRESMAX                  = 220000"))
    assert read_tir(path).get("PRESMAX") == 220000
    text = SMALL.replace("NOMPRES                  = 220000", "NOMPRES                  = 5e5")
    _refused(tmp_path, text, _line_of(text, "NOMPRES"), "NOMPRES",
             ["outside the file's stated range", "PRESMIN, PRESMAX"])
    text = SMALL.replace("FNOMIN                   = 4000", "FNOMIN                   = 'x'")
    _refused(tmp_path, text, _line_of(text, "FNOMIN"), "FNOMIN", ["must be a number"])
    # a coefficient or scaling factor as text: its line named when the file is read
    text = SMALL.replace("PDX1                     = 1.1", "PDX1                     = 'abc'")
    _refused(tmp_path, text, _line_of(text, "PDX1"), "PDX1", ["must be a number", "'abc'"])


def test_the_shipped_sample_reads_as_mf61_with_its_source_stated():
    tir = read_tir(SAMPLE)
    assert tir.version == "6.1" and tir.unknown_keys == []
    header = "\n".join(tir.preamble)
    assert "Project Chrono" in header and "BSD 3-Clause" in header
    params = MFParams.from_tir(tir)
    assert float(params.FNOMIN) == 3800.0 and float(params.version) == pytest.approx(6.1)


def test_only_line_breaks_end_a_line_and_a_byte_order_mark_is_not_text(tmp_path):
    """Lines end at \\n, \\r\\n or \\r: a latin-1 comment holding \\x85 (cp1252's ellipsis)
    or a form feed stays one line, and the text round-trips; a UTF-8 byte order mark is
    dropped; a UTF-16 file is refused as not text."""
    text = SMALL.replace("! a small MF 6.1 file", "! a small\x85 MF 6.1\x0c file")
    text = text.replace("$Magic Formula version number", "$Magic\x1cFormula version number")
    assert format_tir(parse_tir(text)) == text
    path = tmp_path / "odd.tir"
    path.write_bytes(text.encode("latin-1"))
    assert read_tir(path).version == "6.1"
    path.write_bytes(b"\xef\xbb\xbf" + SMALL.encode("latin-1"))
    assert read_tir(path).sections == parse_tir(SMALL).sections
    path.write_bytes(SMALL.encode("utf-16"))
    with pytest.raises(TirError, match="not a text file"):
        read_tir(path)


def test_a_fractional_version_and_a_word_for_a_slip_range_are_refused(tmp_path):
    """FITTYP 6.1 is not version 6 (MF 5.2): it is refused, not truncated; the slip
    ratio's range (KPUMIN, KPUMAX) must be numbers like every stated range."""
    text = SMALL.replace("= 61 ", "= 6.1")
    _refused(tmp_path, text, _line_of(text, "FITTYP"), "FITTYP", ["unknown Magic Formula "
                                                                   "version", "6.1"])
    text = SMALL.replace("[SLIP_ANGLE_RANGE]", "[LONG_SLIP_RANGE]\nKPUMIN = 'abc'\n"
                         "KPUMAX = 1.5\n[SLIP_ANGLE_RANGE]")
    _refused(tmp_path, text, _line_of(text, "KPUMIN"), "KPUMIN", ["must be a number", "abc"])


def test_write_tir_refuses_what_is_not_a_property_file(tmp_path):
    with pytest.raises(TypeError, match="write_tir.tir must be a TirFile, got str"):
        write_tir(tmp_path / "a.tir", SMALL)
    assert not (tmp_path / "a.tir").exists()


def test_a_key_in_two_sections_must_have_one_value_and_units_are_given_once(tmp_path):
    """Readers differ in which of two entries they take (the first here, the last in
    others), so a key in two sections with different values is refused; the same value
    twice is kept. A second [UNITS] would be ignored by every lookup, so it is refused."""
    text = SMALL.replace("[MODEL]\n", "[MODEL]\nFNOMIN = 3000\n")
    _refused(tmp_path, text, _line_of(text, "FNOMIN                   = 4000"), "FNOMIN",
             ["4000 here, in [VERTICAL]", "3000 in [MODEL] on line 10", "one value"])
    same = parse_tir(SMALL.replace("[MODEL]\n", "[MODEL]\nFNOMIN = 4000.0\n"))
    assert same.get("FNOMIN") == 4000.0
    # replace changes every entry of the key, so the copy stays readable
    changed = same.replace(FNOMIN=3500)
    assert [e.value for _, e in changed.entries() if e.key == "FNOMIN"] == [3500, 3500]
    text = SMALL.replace("[MODEL]\n", "[UNITS]\nLENGTH = 'mm'\n[MODEL]\n")
    _refused(tmp_path, text, _line_of(text, "[MODEL]") - 2, None,
             ["a second [UNITS] section", "first is on line 3"])


def test_replace_puts_a_new_key_in_its_home_section_and_refuses_bad_values():
    """MASS is both a unit's name in [UNITS] and the tyre's mass in [INERTIA]: a new MASS
    goes to [INERTIA], where `get` finds it. The copy is read again from its text: its line
    numbers are the written file's, and a value outside its range is refused there."""
    tir = parse_tir(SMALL)
    heavy = tir.replace(MASS=9.3)
    assert heavy.get("MASS") == 9.3 and heavy.units["MASS"] == "kg"
    assert heavy.section("INERTIA").entries["MASS"].line == len(SMALL.splitlines()) + 2
    assert heavy.section("UNITS") == tir.section("UNITS")
    with pytest.raises(TirError, match="PCY1: -1.0 is outside its stated range"):
        tir.replace(PCY1=-1.0)
    with pytest.raises(TypeError, match="replace: PDY1 must be a number, a string or None, "
                                        "got bool"):
        tir.replace(PDY1=True)
    with pytest.raises(ValueError, match="replace: PDY1 must be finite, got nan"):
        tir.replace(PDY1=math.nan)
    with pytest.raises(ValueError, match="TYRESIDE's string 'LEFT\\\\nX' holds a line break"):
        tir.replace(TYRESIDE="LEFT\nX")
    with pytest.raises(ValueError, match="'1PDY' is not a key name"):
        tir.replace(**{"1PDY": 1.0})
