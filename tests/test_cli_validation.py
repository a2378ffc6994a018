"""Bad command-line input, as a user types it: every case ends with exit status 2, a message
naming the option (or the file) as typed, no traceback and nothing written, before any
compilation (the cases run in-process, in milliseconds; a case that compiled would take
seconds and the sweep's axis check is the only one that builds a model)."""

import argparse

import pytest

from vehsim import cli
from vehsim.cli import _options


def _run(argv, capsys):
    """(exit status, stderr) of ``vehsim ARGV`` in this process."""
    try:
        code = cli.main([str(a) for a in argv])
    except SystemExit as e:  # argparse's own errors
        code = e.code
    return code, capsys.readouterr().err


BAD = {
    # sweep
    "vehicle preset of another kind": (["sweep", "--vehicle", "table3"], "--vehicle"),
    "tire preset of another kind": (["sweep", "--tire", "table3"], "--tire"),
    "no samples": (["sweep", "--samples", "0"], "--samples"),
    "negative speed": (["sweep", "--speed", "-3"], "--speed"),
    "zero duration": (["sweep", "--duration", "0"], "--duration"),
    "nan duration": (["sweep", "--duration", "nan"], "--duration"),
    "axis given twice": (["sweep", "--set", "m=1200", "--set", "m=1400"], "--set m"),
    "axis value not finite": (["sweep", "--set", "m=1200,inf"], "--set m"),
    "output extension": (["sweep", "--out", "{tmp}/s.csv"], "--out"),
    "negative speed on an axis": (["sweep", "--set", "speed=-3,2", "--out", "{tmp}/s.json"],
                                  "speed"),
    "axis speed beyond --speed's range": (["sweep", "--set", "speed=20,1e6", "--out",
                                           "{tmp}/s.json"], "--set speed: must be a finite "
                                          "number in (0, 100] m/s"),
    # brake
    "nan speed": (["brake", "--speed", "nan"], "--speed"),
    "speed beyond range": (["brake", "--speed", "1000"], "--speed"),
    "unknown surface": (["brake", "--surface", "moon"], "--surface"),
    "unknown controller": (["brake", "--controller", "pid"], "--controller"),
    "change by distance and time": (["brake", "--change-to", "ice", "--change-distance", "5",
                                     "--change-time", "3"], "--change-time"),
    "change without a surface": (["brake", "--change-distance", "5"], "--change-to"),
    "surface change without where": (["brake", "--change-to", "ice"], "--change-to"),
    "negative change distance": (["brake", "--change-to", "ice", "--change-distance", "-1"],
                                 "--change-distance"),
    "negative seed": (["brake", "--seed", "-1"], "--seed"),
    # optimise
    "no starts": (["optimise", "corner90", "--starts", "0"], "--starts"),
    "one segment": (["optimise", "corner90", "--segments", "1"], "--segments"),
    "no iterations": (["optimise", "corner90", "--max-iter", "0"], "--max-iter"),
    "no friction": (["optimise", "corner90", "--friction", "0"], "--friction"),
    "negative time budget": (["optimise", "corner90", "--tf-max", "-1"], "--tf-max"),
    "no RK4 step": (["optimise", "corner90", "--steps-per-stage", "0"], "--steps-per-stage"),
    "too many interior points": (["optimise", "corner90", "--interior-points", "9"],
                                 "--interior-points"),
    # fit
    "zero radius": (["fit", "{tmp}/x.csv", "--radius", "0"], "--radius"),
    "no fit starts": (["fit", "{tmp}/x.csv", "--starts", "0"], "--starts"),
    "missing data file": (["fit", "{tmp}/missing.csv"], "missing.csv"),
}


@pytest.mark.parametrize("case", list(BAD), ids=list(BAD))
def test_bad_input_exits_2_naming_the_option_and_writes_nothing(case, tmp_path, capsys,
                                                               monkeypatch):
    argv, option = BAD[case]
    monkeypatch.chdir(tmp_path)
    out = tmp_path / "out"
    argv = [a.format(tmp=tmp_path) for a in argv]
    if not any(a == "--out" for a in argv):
        argv += ["--out", str(out)]
    code, err = _run(argv, capsys)
    assert code == 2, err
    assert option in err, err
    assert "Traceback" not in err
    assert sorted(p.name for p in tmp_path.rglob("*")) == [], "a file was written"


def test_sweep_refuses_a_model_value_before_announcing_the_run(tmp_path, capsys):
    code, err = _run(["sweep", "--set", "m=1200,-1200", "--out", tmp_path / "s.json"], capsys)
    assert code == 2 and "HalfCarParams.m must lie in (0, inf), got -1200" in err, err
    assert "members x" not in err, err  # the run's announcement comes after every check
    assert list(tmp_path.iterdir()) == []


def test_values_that_start_with_a_minus_are_read_as_values(capsys):
    """A list whose first number is negative is a value, not an unknown option; a negative
    load then meets the option's own range check, named."""
    parser = cli.build_parser()
    args = parser.parse_args(["drive", "--road", "sturn", "--patch", "-5,2,3,0.5"])
    assert args.patch == [(-5.0, 2.0, 3.0, 0.5)]
    args = parser.parse_args(["tire", "fit-lugre", "x.tir", "--loads", "-.5e3,3800"])
    assert args.loads == "-.5e3,3800"
    with pytest.raises(SystemExit):  # an option that is not one is still refused
        parser.parse_args(["sweep", "-x"])
    assert "unrecognized arguments: -x" in capsys.readouterr().err


def test_option_types_check_ranges_and_parse_good_values():
    speed = _options.number(1.0, 100.0, lower_open=True, unit="m/s")
    assert speed("30") == 30.0 and speed("100") == 100.0
    for bad in ("1", "100.5", "nan", "inf", "-inf", "fast"):
        with pytest.raises(argparse.ArgumentTypeError, match=r"\(1, 100\] m/s"):
            speed(bad)
    never = _options.number(0.0, unit="m", allow_inf=True)
    assert never("inf") == float("inf") and never("0") == 0.0
    with pytest.raises(argparse.ArgumentTypeError):
        never("-inf")
    count = _options.integer(2, 5)
    assert count("2") == 2 and count("5") == 5
    for bad in ("1", "6", "2.5", "two"):
        with pytest.raises(argparse.ArgumentTypeError, match=r"\[2, 5\]"):
            count(bad)
    assert _options.output_file("--out", "a.NC", {".json": "json", ".nc": "netcdf"}) == "netcdf"
