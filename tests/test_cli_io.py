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


def test_cli_parses_reproduce_options():
    args = cli.build_parser().parse_args(["reproduce", "--full", "--out", "x", "--only", "combined"])
    assert (args.quick, args.out, args.only) == (False, "x", ["combined"])
    args = cli.build_parser().parse_args(["reproduce"])
    assert args.quick is True and args.out == "results"


def test_cli_reports_unknown_section_as_error(tmp_path, capsys):
    rc = cli.main(["reproduce", "--out", str(tmp_path), "--only", "no-such-section"])
    assert rc == 2
    assert "no section matches" in capsys.readouterr().err


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
