import json
import math

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
