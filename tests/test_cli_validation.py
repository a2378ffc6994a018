"""Bad command-line input, as a user types it: every case ends with exit status 2, a message
naming the option (or the file) as typed, no traceback and nothing written, before any
compilation (the cases run in-process, in milliseconds; a case that compiled would take
seconds and the sweep's axis check is the only one that builds a model)."""

import argparse
import csv
import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

import vehsim
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
    "axis value in digit groups": (["sweep", "--set", "m=1_200"],
                                   "--set m: values must be numbers, got '1_200'"),
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
    "a coordinator without a port": (["sweep", "--coordinator", "notahost", "--num-processes",
                                      "2", "--process-id", "0", "--out", "{tmp}/s.json"],
                                     "--coordinator must be HOST:PORT"),
    "speed as an option and as an axis": (["sweep", "--speed", "30", "--set", "speed=10",
                                           "--out", "{tmp}/s.json"], "--set speed"),
    "minus infinity as a value": (["brake", "--speed", "-inf"],
                                  "--speed: must be a finite number in (1, 100] m/s, got '-inf'"),
    "a change that never comes": (["brake", "--change-to", "ice", "--change-distance", "inf"],
                                  "finite --change-distance"),
    # optimise
    "a road file's margin on a benchmark road": (["optimise", "corner90", "--margin", "2"],
                                                 "--margin applies to --road-file"),
    "a road file's start speed on a benchmark road": (
        ["optimise", "corner90", "--start-speed", "5"], "--start-speed applies"),
    "a missing road file": (["optimise", "--road-file", "{tmp}/nope.csv"], "--road-file"),
    "a margin wider than the road": (["optimise", "--track", "Oschersleben", "--margin", "9"],
                                     "--margin 9 m leaves no road: it must be below half the "
                                     "road's width, 4.197 m where it is narrowest"),
    "a live log that is quiet": (["optimise", "corner90", "--live", "--quiet"],
                                 "--live prints every iteration and --quiet none"),
    "a change to the same surface": (["brake", "--surface", "ice", "--change-to", "ice",
                                      "--change-distance", "5"],
                                     "--change-to ice is the --surface already"),
    "a time budget for the minimum time": (["optimise", "corner90", "--tf-max", "3"],
                                           "--tf-max is the time budget of --objective "
                                           "max-exit"),
    "max-exit on a road file without a budget": (
        ["optimise", "--road-file", "{tmp}/x.csv", "--objective", "max-exit"],
        "--objective max-exit on a road file needs --tf-max"),
    # drive
    "a missing road file to drive": (["drive", "--road-file", "{tmp}/nope.csv"], "--road-file"),
    "a patch at minus infinity": (["drive", "--road", "corner90", "--patch", "-inf,2,3,0.5"],
                                  "--patch: must be X,Y,RADIUS,SCALE"),
    "a patch in digit groups": (["drive", "--road", "corner90", "--patch", "1_0,2,3,0.5"],
                                "--patch: must be X,Y,RADIUS,SCALE"),
    "frames without an animation": (["drive", "--road", "corner90", "--frame-every", "5",
                                     "--no-animation"], "--frame-every"),
    # estimate
    "a tire for the peak estimator": (["estimate", "{braking}", "--estimator", "peak",
                                       "--kappa0", "3"], "--kappa0 does not apply"),
    "a window for the observer": (["estimate", "{braking}", "--window", "5"],
                                  "--window does not apply"),
    "a sample time not a multiple of the record's": (
        ["estimate", "{braking}", "--sample-time", "0.003"], "--sample-time (0.003 s)"),
    "a folder for a braking": (["estimate", "{tmp}"], "a folder, not a braking file"),
    "a normal load too small for the torques": (
        ["estimate", "{braking}", "--normal-load", "10"],
        "F_n = 10 N from --normal-load): no tire brakes with that; is the column in N m, or "
        "--normal-load too small?"),
    "an estimator sample longer than a tenth of the record": (
        ["estimate", "{braking}", "--sample-time", "0.5"],
        "--sample-time 0.5 s leaves 4 estimator samples in the record's 1.876 s: at least 10"),
    "a window longer than the record": (
        ["estimate", "{braking}", "--estimator", "mhe", "--sample-time", "0.1", "--window", "40"],
        "--window 40 needs more than 40 estimator samples, and the record's 1.876 s give 19 at "
        "a sample time of 0.1 s"),
    "a default window longer than the record": (
        ["estimate", "{braking}", "--estimator", "mhe", "--sample-time", "0.1"],
        "--window 20 (the default) needs more than 20 estimator samples"),

    # fit
    "zero radius": (["fit", "{tmp}/x.csv", "--radius", "0"], "--radius"),
    "no fit starts": (["fit", "{tmp}/x.csv", "--starts", "0"], "--starts"),
    "missing data file": (["fit", "{tmp}/missing.csv"], "missing.csv"),
    # empty words, which would read as the current folder or match everything
    "an empty output folder": (["estimate", "{braking}", "--out", ""],
                               "--out: an empty file name"),
    "an empty road file": (["optimise", "--road-file", ""], "--road-file: an empty file name"),
    "an empty tire": (["estimate", "{braking}", "--tire", ""], "--tire: an empty name"),
    "an empty section word": (["reproduce", "--tiny", "--only", ""],
                              "--only: an empty word"),
    "a drive shorter than a sample": (["drive", "--duration", "0.01"], "--duration"),
    "an unreadable road file": (["optimise", "--road-file", "/proc/self/mem"],
                                "/proc/self/mem: cannot read it"),
}
BRAKING = Path(vehsim.__file__).parent / "data" / "brakings" / "braking_1.csv"


@pytest.mark.parametrize("case", list(BAD), ids=list(BAD))
def test_bad_input_exits_2_naming_the_option_and_writes_nothing(case, tmp_path, capsys,
                                                               monkeypatch):
    argv, option = BAD[case]
    monkeypatch.chdir(tmp_path)
    out = tmp_path / "out"
    argv = [a.format(tmp=tmp_path, braking=BRAKING) for a in argv]
    if not any(a == "--out" for a in argv):
        argv += ["--out", str(out)]
    code, err = _run(argv, capsys)
    assert code == 2, err
    assert option in err, err
    assert "Traceback" not in err
    assert sorted(p.name for p in tmp_path.rglob("*")) == [], "a file was written"


def test_sweep_refuses_a_model_value_before_announcing_the_run(tmp_path, capsys):
    code, err = _run(["sweep", "--set", "m=1200,-1200", "--out", tmp_path / "s.json"], capsys)
    assert code == 2 and ("--set m=-1200: HalfCarParams.m must lie in (0, inf), got -1200"
                          in err), err
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


def _braking_without(tmp, name, column, value=None, keep_first=False):
    """braking_1 (and its side file) in `tmp` as NAME, its `column` set to `value` (None:
    the column left out), on every row or (`keep_first`) every row but the first."""
    rows = list(csv.reader(BRAKING.read_text().splitlines()))
    j = rows[0].index(column)
    for row in rows:
        if value is None:
            del row[j]
        elif row is not rows[0] and not (keep_first and row is rows[1]):
            row[j] = value
    (tmp / f"{name}.csv").write_text("\n".join(",".join(r) for r in rows) + "\n")
    shutil.copy(BRAKING.with_suffix(".json"), tmp / f"{name}.json")
    return tmp / f"{name}.csv"


def _road(tmp, name, scale):
    """A 20-point arc of the unit circle scaled by `scale` [m], 1 m wide each side."""
    import numpy as np

    a = np.linspace(0.0, 0.5, 20)
    rows = ["x_m,y_m,w_tr_right_m,w_tr_left_m"] + [
        f"{scale * np.cos(t):.17g},{scale * np.sin(t):.17g},{min(1.0, 0.1 * scale):.17g},"
        f"{min(1.0, 0.1 * scale):.17g}" for t in a]
    (tmp / f"{name}.csv").write_text("\n".join(rows) + "\n")
    return tmp / f"{name}.csv"


def _road_with_header(tmp, header):
    """`_road`'s 30 m arc with another header line (and a column more per row)."""
    lines = _road(tmp, "named", 30.0).read_text().splitlines()
    path = tmp / "named.csv"
    path.write_text("\n".join([header] + [f"{row},0" for row in lines[1:]]) + "\n")
    return path


def _tir_with(tmp, key, value):
    """The shipped sample .tir file with `key`'s value replaced by the text `value`."""
    src = next((Path(vehsim.__file__).parent / "data" / "tires").glob("*.tir"))
    lines = src.read_text().splitlines()
    i = next(i for i, line in enumerate(lines) if line.split("=")[0].strip() == key)
    lines[i] = f"{key} = {value}"
    (tmp / "bad.tir").write_text("\n".join(lines) + "\n")
    return tmp / "bad.tir"


BAD_FILES = {
    "a coefficient beyond the double range": (
        lambda tmp: ["tire", "show", _tir_with(tmp, "PDX1", "1e400")],
        "PDX1: the number '1e400' is not finite"),
    "a road shorter than a car": (
        lambda tmp: ["optimise", "--road-file", _road(tmp, "tiny", 1e-3)],
        "a road must be 5 m to 100000 m long"),
    "a road longer than 100 km": (
        lambda tmp: ["drive", "--road-file", _road(tmp, "huge", 1e6)],
        "a road must be 5 m to 100000 m long"),
    "a normal load of 0 throughout": (
        lambda tmp: ["fit", _braking_without(tmp, "unloaded", "F_n", "0")],
        "'F_n' is 0 throughout"),
    "a closed-loop fit without the brake torque": (
        lambda tmp: ["fit", _braking_without(tmp, "no_torque", "T_b"), "--closed-loop"],
        "--closed-loop needs the column 'T_b'"),
    "a road column named twice": (
        lambda tmp: ["optimise", "--road-file", _road_with_header(
            tmp, "x_m,y_m,w_tr_right_m,w_tr_left_m,x_m")], "column(s) x_m named twice"),
    "a record whose wheel speed is missing throughout": (
        lambda tmp: ["estimate", _braking_without(tmp, "no_wheel", "omega", "nan",
                                                  keep_first=True)],
        "column 'omega' has 1 measured samples of 939"),
    "a record of a car at rest": (
        lambda tmp: ["estimate", _braking_without(tmp, "at_rest", "v", "0")],
        "column 'v' never exceeds 1 m/s"),
    "a brake torque in the wrong unit": (
        lambda tmp: ["estimate", _braking_without(tmp, "kilo_torque", "T_b", "1e6")],
        "'T_b': 1e+06 N m is more than 100 r F_n"),
}


@pytest.mark.parametrize("case", list(BAD_FILES), ids=list(BAD_FILES))
def test_bad_input_files_exit_2_naming_what_is_wrong_and_write_nothing(case, tmp_path, capsys,
                                                                      monkeypatch):
    make, message = BAD_FILES[case]
    inputs = tmp_path / "in"
    inputs.mkdir()
    argv = make(inputs)
    argv += [] if argv[:2] == ["tire", "show"] else ["--out", tmp_path / "out"]
    before = sorted(tmp_path.rglob("*"))
    monkeypatch.chdir(tmp_path)
    code, err = _run(argv, capsys)
    assert code == 2 and message in err, err
    assert "Traceback" not in err
    assert sorted(tmp_path.rglob("*")) == before, "a file was written"


def test_tire_plot_refuses_its_default_output_before_computing(tmp_path, capsys, monkeypatch):
    """Without --out the figure goes to the current folder; one that cannot be written in
    is refused at once, naming the default (permissions are not enforced for root, so the
    check's view of them is what is replaced)."""
    monkeypatch.chdir(tmp_path)
    monkeypatch.setattr(cli._options.os, "access", lambda *a: False)
    tir = next((Path(vehsim.__file__).parent / "data" / "tires").glob("*.tir"))
    code, err = _run(["tire", "plot", tir], capsys)
    assert code == 2 and "--out (its default" in err and "cannot write in '.'" in err, err
    assert list(tmp_path.iterdir()) == []


def test_a_cache_folder_that_cannot_be_made_is_named_without_a_traceback(tmp_path, capsys,
                                                                          monkeypatch):
    (tmp_path / "a_file").write_text("")
    monkeypatch.setenv("VEHSIM_CACHE_DIR", str(tmp_path / "a_file"))
    monkeypatch.delenv("JAX_COMPILATION_CACHE_DIR", raising=False)
    monkeypatch.delenv("VEHSIM_NO_COMPILATION_CACHE", raising=False)
    import jax

    before = jax.config.jax_compilation_cache_dir  # the suite's shared cache, if any
    jax.config.update("jax_compilation_cache_dir", None)
    try:
        code, err = _run(["sweep", "--out", tmp_path / "sweep.json"], capsys)
    finally:
        jax.config.update("jax_compilation_cache_dir", before)
    assert code == 2 and "compilation cache's folder cannot be used" in err, err
    assert "VEHSIM_CACHE_DIR" in err and "Traceback" not in err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a_file"]


def test_a_cache_switch_that_is_neither_yes_nor_no_is_refused(tmp_path, capsys, monkeypatch):
    monkeypatch.setenv("VEHSIM_NO_COMPILATION_CACHE", "sometimes")
    code, err = _run(["sweep", "--out", tmp_path / "sweep.json"], capsys)
    assert code == 2 and "VEHSIM_NO_COMPILATION_CACHE='sometimes': expected" in err, err
    assert "Traceback" not in err and list(tmp_path.iterdir()) == []


def test_estimate_notes_a_slip_that_mistaken_units_give(capsys):
    """A record whose wheel speed is in rpm (slips near 8) gets the note `vehsim fit`
    gives, before the estimate; the shipped record in rad/s gets none. Missing wheel
    speeds (nan) are left out of the test."""
    import numpy as np

    from vehsim.cli.estimate import _check_speeds
    from vehsim.identify.braking import load_braking

    d = load_braking(BRAKING)
    v, omega, r = np.asarray(d.v), np.asarray(d.omega), float(d.r)
    omega = np.where(np.arange(omega.size) % 3 == 0, np.nan, omega)
    _check_speeds("b.csv", v, omega, r)
    assert capsys.readouterr().err == ""
    _check_speeds("b.csv", v, omega * 60.0 / (2.0 * np.pi), r)
    err = capsys.readouterr().err
    assert err.startswith("note: b.csv: the slip (omega r - v)/v reaches 8."), err
    assert "check the units (omega in rad/s" in err


@pytest.mark.parametrize("value", ["0", " 00"])
def test_a_cpu_device_count_jax_cannot_start_with_is_refused(value, tmp_path, capsys,
                                                             monkeypatch):
    """JAX takes JAX_NUM_CPU_DEVICES=0 at import and fails with a traceback at the first
    computation; the command refuses it first, naming the variable and its range."""
    monkeypatch.setenv("JAX_NUM_CPU_DEVICES", value)
    code, err = _run(["sweep", "--out", tmp_path / "sweep.json"], capsys)
    assert code == 2 and f"JAX_NUM_CPU_DEVICES='{value}': must be a whole number >= 1" in err
    assert "Traceback" not in err and list(tmp_path.iterdir()) == []
    assert cli.main(["--version"]) == 0  # what needs no computation still answers
    capsys.readouterr()
    for fine in ("2", "-1", "-2", ""):  # a count, JAX's "not set" (negative), empty
        monkeypatch.setenv("JAX_NUM_CPU_DEVICES", fine)
        assert cli._jax_environment_error() is None


@pytest.mark.parametrize("how", ["program", "library"])
def test_a_cpu_device_count_jax_cannot_read_is_refused_before_jax_starts(how):
    """JAX's own import refuses a JAX_NUM_CPU_DEVICES that is not a number with a traceback;
    vehsim's import names the variable and its range first: as the command line's error
    (status 2, no traceback) under the ``vehsim`` program, as a ValueError in a library."""
    env = dict(os.environ, JAX_NUM_CPU_DEVICES="two")
    args = ["-m", "vehsim", "--version"] if how == "program" else ["-c", "import vehsim"]
    done = subprocess.run([sys.executable, *args], env=env, capture_output=True, text=True,
                          timeout=120)
    message = "JAX_NUM_CPU_DEVICES='two': must be a whole number >= 1"
    if how == "program":
        assert done.returncode == 2 and done.stdout == "", done
        assert done.stderr.startswith(f"vehsim: error: {message}"), done.stderr
        assert "Traceback" not in done.stderr
    else:
        assert done.returncode == 1 and f"ValueError: {message}" in done.stderr, done.stderr
        assert "jax_num_cpu_devices" not in done.stderr  # refused before JAX's import


def test_a_mass_too_small_for_the_torques_is_named_as_the_load_s_source(tmp_path, capsys):
    """A record without F_n takes the load as m g: a --mass too small for its torques is
    refused naming where m came from and offering --mass as a cause."""
    rows = list(csv.reader(BRAKING.read_text().splitlines()))
    drop = rows[0].index("F_n")
    path = tmp_path / "no_load.csv"
    path.write_text("\n".join(",".join(r[:drop] + r[drop + 1:]) for r in rows) + "\n")
    shutil.copy(BRAKING.with_suffix(".json"), tmp_path / "no_load.json")
    code, err = _run(["estimate", path, "--mass", "1", "--out", tmp_path / "out"], capsys)
    assert code == 2 and "F_n = 9.8" in err and "N from m g (m = 1 kg from --mass))" in err, err
    assert err.rstrip().endswith("is the column in N m, or --mass too small?"), err
    assert not (tmp_path / "out").exists()
