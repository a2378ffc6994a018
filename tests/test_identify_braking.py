"""Braking data format: round trip, and one test per kind of bad file."""

import json

import jax.numpy as jnp
import numpy as np
import pytest

from vehsim.identify.braking import BrakingData, load_braking, save_braking, shipped_brakings


GOOD = "t,v,omega,F_x,F_n,T_b\n0,20,66.6,0,4000,0\n0.002,19.99,66.5,-100,4010,10\n" \
       "0.004,19.98,66.3,-250,4020,20\n0.006,19.97,66.0,-400,4030,30\n"


def _write(tmp_path, text, meta={"r": 0.3}, name="b.csv"):
    path = tmp_path / name
    path.write_text(text)
    if meta is not None:
        path.with_suffix(".json").write_text(json.dumps(meta))
    return path


def test_round_trip(tmp_path):
    d = load_braking(_write(tmp_path, GOOD, {"r": 0.3, "m": 400, "J": 1.2}))
    assert len(d) == 4 and float(d.r) == 0.3 and float(d.m) == 400.0
    np.testing.assert_array_equal(np.asarray(d.F_x), [0, -100, -250, -400])
    np.testing.assert_allclose(np.asarray(d.v_r), 0.3 * np.asarray(d.omega) - np.asarray(d.v))
    out = save_braking(d, tmp_path / "c.csv")
    e = load_braking(out)
    for field in ("t", "v", "omega", "F_x", "F_n", "T_b"):
        np.testing.assert_array_equal(np.asarray(getattr(e, field)), np.asarray(getattr(d, field)))
    assert float(e.J) == 1.2


def test_shipped_brakings_load_and_are_physical():
    files = shipped_brakings()
    assert {"braking_1", "braking_2", "braking_3", "braking_mf"} <= set(files)
    for name, path in files.items():
        d = load_braking(path)
        assert d.T_b is not None and d.m is not None and d.J is not None
        # braking: the vehicle decelerates and the mean force opposes the motion
        assert float(d.v[-1]) < float(d.v[0]) - 5.0
        assert float(jnp.mean(d.F_x)) < 0
        # momentum: m (v_end - v_0) = integral of F_x dt, within the sensor noise
        impulse = float(jnp.trapezoid(d.F_x, d.t))
        assert abs(float(d.m) * float(d.v[-1] - d.v[0]) - impulse) < 0.03 * abs(impulse)


@pytest.mark.parametrize(
    "text, meta, match",
    [
        # missing column
        ("t,v,omega,F_n\n0,1,2,3\n1,1,2,3\n2,1,2,3\n", {"r": 0.3}, r"column 'F_x': missing"),
        # NaN
        (GOOD.replace("-250", "nan"), {"r": 0.3}, r"row 3, column 'F_x'.*finite"),
        # inf
        (GOOD.replace("19.99", "inf"), {"r": 0.3}, r"row 2, column 'v'.*finite"),
        # not a number
        (GOOD.replace("66.5", "abc"), {"r": 0.3}, r"row 2, column 'omega'.*not a number"),
        # non-increasing time
        (GOOD.replace("0.004,", "0.002,"), {"r": 0.3}, r"row 3, column 't'.*increase"),
        # negative load
        (GOOD.replace("4020", "-4020"), {"r": 0.3}, r"row 3, column 'F_n'.*>= 0"),
        # negative speed (a braking is forwards)
        (GOOD.replace("19.99", "-19.99"), {"r": 0.3}, r"row 2, column 'v'.*>= 0 \(the forward"),
        # negative brake torque
        (GOOD.replace(",30\n", ",-30\n"), {"r": 0.3}, r"row 4, column 'T_b'.*>= 0"),
        # inconsistent lengths (a short row)
        (GOOD.replace("-100,4010,10", "-100,4010"), {"r": 0.3},
         r"row 2, column 'T_b'.*inconsistent lengths"),
        # missing radius
        (GOOD, None, r"radius 'r'"),
        # invalid radius
        (GOOD, {"r": -0.3}, r"'r' \[m\] must lie in \(0, 5\]"),
        # too short
        ("t,v,omega,F_x,F_n\n0,1,2,3,4\n", {"r": 0.3}, r"at least 3 data rows"),
    ],
    ids=["missing_column", "nan", "inf", "not_a_number", "time_not_increasing",
         "negative_load", "negative_speed", "negative_torque", "inconsistent_lengths",
         "missing_radius", "invalid_radius", "too_short"],
)
def test_loader_rejects_bad_file(tmp_path, text, meta, match):
    with pytest.raises(ValueError, match=match):
        load_braking(_write(tmp_path, text, meta))


def test_blank_lines_end_a_file_but_not_its_middle(tmp_path):
    """Blank lines after the last row (a common file ending) are no rows; one between
    rows is still an inconsistent row, named."""
    d = load_braking(_write(tmp_path, GOOD + "\n\n"))
    np.testing.assert_array_equal(np.asarray(d.t), [0.0, 0.002, 0.004, 0.006])
    rows = GOOD.split("\n")
    middle = "\n".join(rows[:2] + [""] + rows[2:])
    with pytest.raises(ValueError, match=r"row 2, column 't'.*inconsistent lengths"):
        load_braking(_write(tmp_path, middle, name="c.csv"))


def test_missing_file(tmp_path):
    with pytest.raises(FileNotFoundError):
        load_braking(tmp_path / "nope.csv")


def test_radius_override(tmp_path):
    d = load_braking(_write(tmp_path, GOOD, None), r=0.31)
    assert float(d.r) == 0.31
    assert isinstance(d, BrakingData)


def test_slip_sign_note_flags_records_in_other_units_or_signs():
    """The shipped brakings pass; the same with omega in rpm, or the force's sign flipped,
    get a note naming what is off."""
    import equinox as eqx

    from vehsim.identify.braking import slip_sign_note

    d = load_braking(shipped_brakings()["braking_1"])
    assert slip_sign_note(d) is None
    rpm = eqx.tree_at(lambda x: x.omega, d, d.omega * 60.0 / (2.0 * np.pi))
    assert "the slip (omega r - v)/v reaches 8." in slip_sign_note(rpm)
    flipped = eqx.tree_at(lambda x: x.F_x, d, -d.F_x)
    assert "the force opposes the slip on 100 % of the slipping samples" in \
        slip_sign_note(flipped)
