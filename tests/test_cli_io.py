import json
import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from vehsim import _io, cli, reproduce


def test_write_json_is_atomic_and_converts_arrays(tmp_path):
    path = tmp_path / "sub" / "r.json"
    _io.write_json(path, {"t_f": jnp.asarray(3.25), "xs": np.arange(3), "bad": math.nan,
                          "worse": [np.inf, -np.inf]})
    data = json.loads(path.read_text())
    assert data == {"t_f": 3.25, "xs": [0, 1, 2], "bad": None, "worse": [None, None]}
    assert [p.name for p in path.parent.iterdir()] == ["r.json"]  # no temporary left behind
    assert path.stat().st_mode & 0o777 == 0o644  # readable by all, as a plain write makes it


def test_write_atomic_keeps_old_file_on_failure(tmp_path):
    path = tmp_path / "r.json"
    _io.write_json(path, {"a": 1})

    with pytest.raises(TypeError):
        _io.write_atomic(path, 12345)  # not str/bytes: the write fails
    assert json.loads(path.read_text()) == {"a": 1}
    assert [p.name for p in tmp_path.iterdir()] == ["r.json"]


def test_a_record_and_its_figure_are_written_together_or_not_at_all(tmp_path):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots()
    ax.plot([0, 1], [1, 0])
    written = _io.write_json_and_figure(tmp_path / "r.json", {"a": 1}, tmp_path / "r.png", fig)
    assert [p.name for p in written] == ["r.json", "r.png"]
    assert json.loads((tmp_path / "r.json").read_text()) == {"a": 1}
    assert (tmp_path / "r.png").read_bytes().startswith(b"\x89PNG")
    (tmp_path / "b" / "r.png").mkdir(parents=True)  # the figure's place taken by a folder
    with pytest.raises(IsADirectoryError, match=r"Is a directory: '[^']*/b/r\.png'$"):
        _io.write_json_and_figure(tmp_path / "b" / "r.json", {"a": 1}, tmp_path / "b" / "r.png",
                                  fig)
    assert [p.name for p in (tmp_path / "b").iterdir()] == ["r.png"]  # no record, no temporary
    (tmp_path / "c" / "r.json").mkdir(parents=True)  # the record's place taken: no figure
    with pytest.raises(IsADirectoryError, match=r"Is a directory: '[^']*/c/r\.json'$"):
        _io.write_json_and_figure(tmp_path / "c" / "r.json", {"a": 1}, tmp_path / "c" / "r.png",
                                  fig)
    assert [p.name for p in (tmp_path / "c").iterdir()] == ["r.json"]
    plt.close(fig)


def test_written_files_are_readable_by_others_under_the_umask(tmp_path):
    """Files are created like any new file (0666 minus the umask), not mkstemp's 0600, and a
    replaced file takes the same mode; the umask is the process's own."""
    import os
    import stat

    mode = lambda p: stat.S_IMODE(os.stat(p).st_mode)  # noqa: E731
    assert _io.FILE_MODE == 0o666 & ~_io._process_umask()
    path = _io.write_json(tmp_path / "r.json", {"a": 1})
    assert mode(path) == _io.FILE_MODE
    if _io.FILE_MODE == 0o644:  # the usual umask 022
        assert mode(path) & stat.S_IROTH
    os.chmod(path, 0o600)
    _io.write_atomic(path, b"x")
    assert mode(path) == _io.FILE_MODE


def test_cli_prints_its_version(capsys):
    import vehsim

    with pytest.raises(SystemExit) as e:
        cli.build_parser().parse_args(["--version"])
    assert e.value.code == 0
    assert capsys.readouterr().out.strip() == f"vehsim {vehsim.__version__}"


def test_cli_parses_reproduce_options():
    args = cli.build_parser().parse_args(["reproduce", "--full", "--out", "x", "--only", "combined"])
    assert (args.quick, args.out, args.only) == (False, "x", ["combined"])
    args = cli.build_parser().parse_args(["reproduce"])
    assert args.quick is True and args.out == "results"


def test_cli_reports_unknown_section_as_error(tmp_path, capsys):
    rc = cli.main(["reproduce", "--out", str(tmp_path / "out"), "--only", "no-such-section"])
    assert rc == 2
    assert "no section matches" in capsys.readouterr().err
    assert not (tmp_path / "out").exists()  # nothing written, not even the folder
    # `--only` without a word is refused, rather than read as every section
    rc = cli.main(["reproduce", "--out", str(tmp_path / "out"), "--only"])
    assert rc == 2 and "--only: expected at least one argument" in capsys.readouterr().err
    assert not (tmp_path / "out").exists()


_OUT_COMMANDS = {  # each command with an output: its arguments, and whether --out is a file
    "reproduce": (["reproduce", "--tiny"], False), "fit": (["fit", "x.csv"], False),
    "optimise": (["optimise", "corner90"], False), "brake": (["brake"], False),
    "estimate": (["estimate", "x.csv"], False), "drive": (["drive", "--road", "sturn"], False),
    "sweep": (["sweep"], True), "tire plot": (["tire", "plot", "x.tir"], True),
    "tire fit-lugre": (["tire", "fit-lugre", "x.tir"], True),
}


@pytest.mark.parametrize("command", list(_OUT_COMMANDS))
def test_an_output_that_cannot_be_written_is_refused_before_any_work(command, tmp_path, capsys,
                                                                     monkeypatch):
    """`--out` naming an existing file where a folder goes (or a folder where a file goes), a
    path under a file, or a folder that cannot be written in (permissions, a read-only file
    system): exit 2 naming --out, before anything runs (the input files do not even exist)
    and with nothing written."""
    args, is_file = _OUT_COMMANDS[command]
    afile = tmp_path / "afile.json"
    afile.write_text("{}")
    cases = [(str(afile / "sub.json"), "is a file, not a folder"),
             (str(tmp_path), "is a folder") if is_file else (str(afile), "is not a folder")]
    for out, message in cases:
        assert cli.main([*args, "--out", out]) == 2
        err = capsys.readouterr().err
        assert "--out" in err and message in err and "Traceback" not in err, err
    target = tmp_path / "results" / ("x.json" if is_file else "")
    real_access = __import__("os").access
    monkeypatch.setattr("os.access", lambda p, mode: False if str(p) == str(tmp_path)
                        else real_access(p, mode))
    assert cli.main([*args, "--out", str(target)]) == 2
    assert "cannot write in" in capsys.readouterr().err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["afile.json"]
    # permission bits that allow it, a folder that refuses files all the same (/proc as the
    # superuser): found by the probe file, before any work
    monkeypatch.setattr("os.access", real_access)
    real_mkstemp = cli._options.tempfile.mkstemp

    def refusing(*a, dir=None, **k):
        if str(dir) == str(tmp_path):
            raise OSError(2, "No such file or directory")
        return real_mkstemp(*a, dir=dir, **k)

    monkeypatch.setattr(cli._options.tempfile, "mkstemp", refusing)
    assert cli.main([*args, "--out", str(target)]) == 2
    err = capsys.readouterr().err
    assert f"cannot write in {str(tmp_path)!r}: no file can be created there" in err, err
    monkeypatch.setattr(cli._options.tempfile, "mkstemp", real_mkstemp)
    cli._options.writable_output("--out", target, "file" if is_file else "folder")  # passes
    assert sorted(p.name for p in tmp_path.iterdir()) == ["afile.json"]  # no probe left


@pytest.mark.parametrize("command", ["fit", "estimate"])
@pytest.mark.parametrize("side, message", [
    ('["r"]', "must be a JSON object"), ('{"r": true}', "'r' must be a number"),
    ('{"r": 1e308}', "'r' [m] must lie in (0, 5]"),
    ('{"r": 0.3, "J": -1}', "'J' [kg m^2] must lie in (0, inf), got -1"),
    ("[" * 100_000 + "]" * 100_000, "invalid JSON side file: nested too deeply"),
    ('{"r": ' + "9" * 5000 + "}", "invalid JSON side file: Exceeds the limit"),
    (None, "the record's side file is a folder"),
])
def test_a_bad_side_file_is_refused_naming_it(command, side, message, tmp_path, capsys):
    """The record's side file (NAME.json) must be a JSON object of positive numbers, the
    radius within --radius's range: otherwise exit 2 naming the file and the key, not a
    traceback (JSON nested past Python's recursion limit, an integer past its digit limit),
    a fit of r = 1 (true), a nonfinite one (1e308) or the default wheel (a folder)."""
    from pathlib import Path

    shipped = Path(_io.__file__).parent / "data" / "brakings" / "braking_1.csv"
    record = tmp_path / "braking.csv"
    record.write_text(shipped.read_text())
    if side is None:  # a folder where the side file goes: not silently the default wheel
        (tmp_path / "braking.json").mkdir()
    else:
        (tmp_path / "braking.json").write_text(side)
    assert cli.main([command, str(record), "--out", str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err
    assert "braking.json" in err and message in err and "Traceback" not in err, err
    assert not (tmp_path / "out").exists()


@pytest.mark.parametrize("args, message", [
    (["sweep", "--num-processes", "2", "--process-id", "1"], "give --distributed"),
    (["sweep", "--coordinator", "127.0.0.1:1", "--num-processes", "2", "--process-id", "5"],
     "--process-id must be in [0, 1]"),
    (["optimise", "--road-file", "{folder}"], "is a folder"),
    (["drive", "--road-file", "{folder}"], "is a folder"),
])
def test_bad_process_ids_and_a_folder_for_a_file_end_with_exit_2(args, message, tmp_path,
                                                                 capsys):
    """No traceback: a process id outside the run's count, or ids without a multi-process
    run; a folder where a road file goes (an OSError, named)."""
    args = [a.format(folder=tmp_path) for a in args]
    assert cli.main([*args, "--out", str(tmp_path / "o.json")]) == 2
    err = capsys.readouterr().err
    assert message in err and "Traceback" not in err, err


@pytest.mark.parametrize("args", [["fit", "{bad}", "--radius", "0.3"], ["estimate", "{bad}"],
                                  ["optimise", "--road-file", "{bad}"]])
def test_a_file_that_is_not_utf8_text_is_refused_naming_it(args, tmp_path, capsys):
    bad = tmp_path / "binary.csv"
    bad.write_bytes(b"\xbc\xff\x00t,v")
    assert cli.main([a.format(bad=bad) for a in args] + ["--out", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err
    assert f"{bad}: not a UTF-8 text file" in err and "Traceback" not in err, err


def test_read_text_drops_a_byte_order_mark(tmp_path):
    path = tmp_path / "x.csv"
    path.write_bytes("\ufefft,v\r\n1,2\r\n".encode())
    assert _io.read_text(path) == "t,v\r\n1,2\r\n"


def test_tire_plot_refuses_a_format_it_cannot_write_before_reading_the_file(tmp_path, capsys):
    # the file does not exist: the output's format is checked first
    assert cli.main(["tire", "plot", str(tmp_path / "none.tir"), "--out",
                     str(tmp_path / "x.txt")]) == 2
    err = capsys.readouterr().err
    assert "--out: the file name must end in .png or .pdf or .svg" in err and "x.txt" in err


def test_every_reproduce_section_is_importable_with_title_and_entry_point():
    import importlib

    for name in reproduce.SECTIONS:
        mod = importlib.import_module(name)
        assert isinstance(mod.TITLE, str) and callable(mod.reproduce)


def test_exit_status_names_each_failing_case_and_its_message(capsys):
    from vehsim import RESULTS
    from vehsim._results import result_message_of_name
    from vehsim.cli._status import exit_status

    assert exit_status("optimise", RESULTS.successful) == 0
    assert capsys.readouterr().err == ""
    assert exit_status("optimise", RESULTS.ip_max_iterations) == 1
    assert capsys.readouterr().err == (
        f"vehsim optimise: ip_max_iterations: {result_message_of_name('ip_max_iterations')}\n")
    assert exit_status("fit: kappa0=1", RESULTS.not_identifiable, "no slip") == 1
    assert capsys.readouterr().err == "vehsim fit: kappa0=1: not_identifiable: no slip\n"
    # a batch: one line per failing case, with how many members it stopped
    cases = (RESULTS.successful, RESULTS.max_steps_reached, RESULTS.nonfinite,
             RESULTS.max_steps_reached)
    batch = jax.tree.map(lambda *v: jnp.stack(v), *cases)
    assert exit_status("sweep", batch) == 1
    err = capsys.readouterr().err.splitlines()
    assert err == [f"vehsim sweep: max_steps_reached (2 of 4): "
                   f"{result_message_of_name('max_steps_reached')}",
                   f"vehsim sweep: nonfinite (1 of 4): {result_message_of_name('nonfinite')}"]


def test_a_failed_solve_ends_the_command_with_its_case_and_message(tmp_path, capsys,
                                                                   monkeypatch):
    """`vehsim sweep` whose solves run out of steps: exit 1, the case and its message on
    stderr, the members written with their status."""
    import vehsim._sweep
    from vehsim._results import result_message_of_name

    sweep = vehsim._sweep.sweep
    monkeypatch.setattr(vehsim._sweep, "sweep", lambda *a, **k: sweep(*a, max_steps=4, **k))
    out = tmp_path / "sweep.json"
    rc = cli.main(["sweep", "--set", "delta=0.02,0.04", "--duration", "1", "--samples", "3",
                   "--out", str(out)])
    assert rc == 1
    err = capsys.readouterr().err
    assert ("vehsim sweep: max_steps_reached (2 of 2): "
            + result_message_of_name("max_steps_reached")) in err
    rows = json.loads(out.read_text())["members"]
    assert [(r["ok"], r["status"]) for r in rows] == [(False, "max_steps_reached")] * 2


def test_units_block_names_every_numeric_field_and_load_result_reads_it_back(tmp_path):
    import vehsim
    from vehsim._result_files import units_block, with_units

    record = {"stopping_distance_m": 41.0, "speed_m_s": 30.0, "distance_over_bound": 1.02,
              "t_f": 3.6, "status": "successful", "ok": True,
              "residuals": {"inf_pr": 1e-9}, "starts": [{"objective": 3.6, "iterations": 28}],
              "states": {"x": [0.0, 1.0], "vx": [20.0, 21.0]}, "theta_true": 1.0,
              "samples": [[1.0, None], [2.0, 3.0]]}
    own = {"residuals.inf_pr": "1", "starts[].objective": "s", "theta_true": "1", "samples": "1"}
    units = units_block(record, own)
    assert units == {"stopping_distance_m": "m", "speed_m_s": "m/s", "distance_over_bound": "1",
                     "t_f": "s", "residuals.inf_pr": "1", "starts[].objective": "s",
                     "starts[].iterations": "1", "states.x": "m", "states.vx": "m/s",
                     "theta_true": "1", "samples": "1"}
    with pytest.raises(ValueError, match="'theta_true'"):  # a writer that forgot a unit
        units_block(record, {k: v for k, v in own.items() if k != "theta_true"})
    path = _io.write_json(tmp_path / "r.json", with_units(record, own))
    back = vehsim.load_result(path)
    assert back["units"] == units
    np.testing.assert_array_equal(back["states"]["vx"], [20.0, 21.0])
    assert isinstance(back["states"]["vx"], np.ndarray)
    assert np.isnan(back["samples"][0, 1]) and back["samples"][1, 1] == 3.0
    assert back["status"] == "successful" and back["starts"][0]["iterations"] == 28
    with pytest.raises(ValueError, match=r"\.json, \.nc and \.csv"):
        vehsim.load_result(tmp_path / "r.txt")
    flags = vehsim.load_result(_io.write_json(tmp_path / "b.json", {"converged": [True, False]}))
    assert flags["converged"] == [True, False]  # booleans stay booleans, not 1.0 and 0.0
    with pytest.raises(FileNotFoundError):
        vehsim.load_result(tmp_path / "missing.json")


def test_units_are_read_from_whole_words_of_a_name():
    from vehsim._result_files import unit_of_name

    for name in ("t_f_over_bound", "mean_iterations", "converged_fraction", "num_steps",
                 "drive_ratio", "seed", "nodes"):
        assert unit_of_name(name) == "1", name
    for name in ("duration", "deceleration", "iteration_time", "calibration"):
        assert unit_of_name(name) != "1", name  # "ratio" inside a word is not a ratio


def test_fit_points_out_a_kappa0_far_from_the_lumped_models_range():
    import types

    from vehsim.cli.fit import kappa0_note

    fit = types.SimpleNamespace(free=("kappa0", "sigma0"), values={"kappa0": 0.11},
                                std_errors={"kappa0": 0.2}, condition_number=3e4)
    note = kappa0_note(fit)
    assert "kappa0 = 0.11 +/- 0.2" in note and "poorly" in note and "3e+04" in note
    assert kappa0_note(types.SimpleNamespace(**{**vars(fit), "values": {"kappa0": 1.4}})) is None
    assert kappa0_note(types.SimpleNamespace(**{**vars(fit), "free": ("sigma0",)})) is None


def test_waiting_line_says_compiling_once_then_loading(tmp_path):
    from vehsim.cli._status import waiting_line

    first = waiting_line(tmp_path, "closed loop", "jit_closed_loop_grid", "30-60 s")
    assert first.startswith("compiling closed loop (30-60 s, this once") and str(tmp_path) in first
    (tmp_path / "jit_closed_loop_grid-abc").write_bytes(b"")
    assert waiting_line(tmp_path, "closed loop", "jit_closed_loop_grid", "30-60 s").startswith(
        "loading the compiled closed loop from the cache")
    assert "cache is off" in waiting_line(None, "closed loop", "jit_closed_loop_grid", "30-60 s")


def test_brake_figure_marks_the_change_and_clips_a_spiking_estimate():
    import argparse

    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from vehsim.cli.brake import figure_title
    from vehsim.plot import braking_figure

    t = np.linspace(0.0, 3.0, 301)
    truth = np.where(t < 1.0, 1.0, 5.0)
    run = dict(ts=t, v=30 - 9 * t, slip=-0.1 + 0 * t, mu=0.8 + 0 * t, theta_hat=truth,
               command=1e3 + 0 * t, torque=9e2 + 0 * t, x=30 * t, theta_true=truth)
    locked = dict(run, theta_hat=np.where((t > 1.0) & (t < 1.2), 40.0, truth))
    fig = braking_figure({"estimate": run, "locked": locked})
    theta = fig.axes[3]
    assert theta.get_yscale() == "linear" and theta.get_ylim() == (0.0, 7.5)
    assert "clipped" in theta.get_ylabel()
    marks = [ln for ln in fig.axes[0].lines if ln.get_linestyle() == "-."]
    assert len(marks) == 2 and marks[0].get_xdata()[0] == pytest.approx(t[np.argmax(t >= 1.0)])
    plt.close(fig)
    fig = braking_figure({"estimate": run})
    assert "clipped" not in fig.axes[3].get_ylabel()
    plt.close(fig)
    args = argparse.Namespace(controller="estimate", ideal_hardware=False, surface="dry_asphalt",
                              change_to="ice", change_distance=20.0, change_time=math.inf,
                              speed=30.0)
    assert figure_title(args) == ("controller 'estimate' (beside a locked wheel), realistic "
                                  "hardware: dry_asphalt, changing to ice at 20 m (dash-dot "
                                  "line), from 30 m/s")


@pytest.mark.parametrize("flags", [("--no-compilation-cache",), ()])
def test_a_command_in_process_leaves_the_callers_cache_settings(tmp_path, capsys, flags):
    """`cli.main` switches JAX's compilation cache on or off for its command only: a caller
    in the same process (a notebook, the tests, whose cache is on) finds its settings as it
    left them, whether the command finished or was refused."""
    from vehsim._compilation import CACHE_SETTINGS

    before = {name: getattr(jax.config, name) for name in CACHE_SETTINGS}
    bad = tmp_path / "bad.csv"
    bad.write_text("# x_m,y_m,w_tr_right_m,w_tr_left_m\n0,0,3,3\n10,0,-1,3\n20,0,3,3\n"
                   "30,0,3,3\n")
    code = cli.main([*flags, "optimise", "--road-file", str(bad), "--out",
                     str(tmp_path / "out")])
    assert code == 2 and "w_tr_right_m must be > 0" in capsys.readouterr().err
    assert {name: getattr(jax.config, name) for name in CACHE_SETTINGS} == before


@pytest.mark.parametrize("command", ["fit", "estimate"])
def test_an_output_folder_that_would_replace_an_input_side_file_is_refused(command, tmp_path,
                                                                           capsys):
    """`vehsim estimate DIR/estimate.csv --out DIR` would write its results over the
    record's side file (its wheel data): refused before any work, exit 2, the side file
    untouched."""
    from pathlib import Path

    shipped = Path(_io.__file__).parent / "data" / "brakings" / "braking_1.csv"
    record = tmp_path / f"{command}.csv"
    record.write_bytes(shipped.read_bytes())
    side = shipped.with_suffix(".json").read_bytes()
    record.with_suffix(".json").write_bytes(side)
    assert cli.main([command, str(record), "--out", str(tmp_path)]) == 2
    err = capsys.readouterr().err
    assert f"writing {command}.json in {str(tmp_path)!r} would replace the side file of" in err
    assert "Traceback" not in err, err
    assert record.with_suffix(".json").read_bytes() == side
    assert sorted(p.name for p in tmp_path.iterdir()) == [f"{command}.csv", f"{command}.json"]
