"""A tyre property file's faces: the LuGre fit to its Magic Formula (checked against the
discrete PDE and `mf_evaluate` called here, in the file's own axes), and `vehsim tire show |
plot | fit-lugre` on the shipped sample (values against `mf6` functions evaluated here) and
on bad input (exit status 2, the file named, nothing written)."""

import json
import math
import os
import subprocess
import sys
from pathlib import Path

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest

from vehsim import RESULTS
from vehsim.cli import main
from vehsim.params import bakker1987
from vehsim.tire.characteristic import (
    MagicFormula1987Characteristic,
    MFCharacteristic,
    tire_characteristic,
)
from vehsim.tire.distributed2d import DistributedLuGre2D, slip_velocities
from vehsim.tire.load import UniformLoad
from vehsim.tire.lugre2d_fit import fit_to_magic_formula, lugre_initial_guess
from vehsim.tire.magic_formula import combined_forces
from vehsim.tire.mf6 import MFParams, MFTire, mf_evaluate
from vehsim.tire.tir import read_tir, shipped_tires


ROOT = Path(__file__).parent.parent
SAMPLE_PATH = shipped_tires()["sample_185_80R14_mf61"]
SAMPLE = read_tir(SAMPLE_PATH)
P = MFParams.from_tir(SAMPLE)
FZ0 = 3800.0
PNG = b"\x89PNG\r\n\x1a\n"


def mf_pure_report_signs(kappa, alpha, Fz):
    """The sample's pure-slip (F_x(kappa), F_y(alpha), M_z(alpha)) with alpha positive when
    the wheel slides to its right: the file's (ISO-W) slip angle is -alpha."""
    fx = np.asarray(mf_evaluate(P, np.asarray(kappa), 0.0, Fz).Fx)
    lat = mf_evaluate(P, 0.0, -np.asarray(alpha), Fz)
    return fx, np.asarray(lat.Fy), np.asarray(lat.Mz)


@eqx.filter_jit
def _pde_steady(model, kappa, alpha, Fz):
    """Steady (F_x, F_y, M_z) of the discrete distributed PDE (one linear solve per axis),
    not the closed-form quadrature the fit uses."""

    def one(k, a):
        v_r, c = slip_velocities(20.0, k, a)
        mu = model.mu(model.steady_state(v_r, c), v_r, c)
        return Fz * mu * jnp.stack([1.0, 1.0, model.params.L])

    return jax.vmap(one)(kappa, alpha)


def measured_errors(params, load, Fz, kappa, alpha):
    """(RMS, max) relative to the peak and the peaks of F_x, F_y, M_z: the PDE against the
    file's Magic Formula, both evaluated here."""
    model = DistributedLuGre2D(params, load, n=48)
    fx = np.asarray(_pde_steady(model, kappa, jnp.zeros_like(kappa), Fz))[:, 0]
    lat = np.asarray(_pde_steady(model, jnp.zeros_like(alpha), alpha, Fz))
    rms, worst, peaks = [], [], []
    for lu, m in zip((fx, lat[:, 1], lat[:, 2]), mf_pure_report_signs(kappa, alpha, Fz)):
        peak = np.abs(m).max()
        rms.append(np.sqrt(np.mean((lu - m) ** 2)) / peak)
        worst.append(np.abs(lu - m).max() / peak)
        peaks.append(peak)
    return np.array(rms), np.array(worst), np.array(peaks)


# --- the fit --------------------------------------------------------------------------------

KAPPA = jnp.array([-0.3, -0.05, 0.03, 0.1, 0.4])
ALPHA = jnp.deg2rad(jnp.array([-15.0, -6.0, -2.0, 2.0, 6.0, 15.0]))
LOADS = (1900.0, 5700.0)
RMS_BOUND = np.array([0.08, 0.20, 0.35])  # F_x, F_y, M_z, relative to each curve's peak


@pytest.fixture(scope="module")
def sample_fit():
    init = lugre_initial_guess(P)
    fit = fit_to_magic_formula(MFTire(P), init, loads=LOADS, kappa=KAPPA, alpha=ALPHA,
                               max_steps=MAX_STEPS, throw=False)
    return init, fit


MAX_STEPS = 300
PHYSICAL = {  # what a tyre's LuGre parameters can be (the fit's start: the file's peaks)
    "sigma0 [1/m]": (10.0, 1000.0), "mu_k": (0.3, 1.5), "mu_s": (0.3, 2.5),
    "L0 [m]": (0.05, 1.0), "patch exponent": (-1.0, 1.0)}


def test_fit_to_a_tir_file_converges_to_physical_parameters(sample_fit):
    """The fit to the sample (two loads, small grids, from `lugre_initial_guess`) holds the
    Stribeck velocity and exponent at the start's 3 m/s and 0.7 (curves at one speed do not
    determine them; fitted, they drift off along a valley of equal losses and the fit
    never converges), and converges: `successful`, in fewer than `MAX_STEPS` steps, its
    message saying how, with MINPACK's numbers of a stationary point; every parameter
    within `PHYSICAL`, mu_k <= mu_s."""
    init, fit = sample_fit
    assert fit.held == ("v_s", "gamma")
    assert fit.result == RESULTS.successful, fit.message
    assert int(fit.num_steps) < MAX_STEPS, fit.message
    assert fit.message.startswith(("converged", "stationary")), fit.message
    assert min(float(fit.gradient_cosine), float(fit.predicted_reduction)) <= 1e-6
    p = fit.params
    assert float(p.v_s) == float(init.v_s) == 3.0 and float(p.gamma) == float(init.gamma) == 0.7
    values = {"sigma0 [1/m]": p.sigma0, "mu_k": p.mu_k, "mu_s": p.mu_s, "L0 [m]": p.L,
              "patch exponent": fit.patch_exponent}
    for name, (lo, hi) in PHYSICAL.items():
        v = np.asarray(values[name])
        assert np.all((v > lo) & (v < hi)), (name, v)
    assert np.all(np.asarray(p.mu_k) <= np.asarray(p.mu_s))
    # had the solver stopped short at this point, the message would say why it is accepted
    short = eqx.tree_at(lambda f: f.solver_result, fit, RESULTS.nonlinear_max_steps_reached)
    assert short.message.startswith("stationary by MINPACK's tests"), short.message
    assert "nonlinear_max_steps_reached" in short.message


def test_fit_to_a_tir_file_reports_what_the_pde_and_the_file_give(sample_fit):
    """The fit to the sample: the errors it reports, relative and in N / N m, are those of
    the discrete PDE at its parameters against `mf_evaluate` at the file's slip angle
    -alpha; each RMS error below the bound (F_x 8 %, F_y 20 %, M_z 35 % of the peak: the
    LuGre force per unit load cannot follow the file's friction falling with load), and
    the sum of squares under half of the start's."""
    init, fit = sample_fit
    assert isinstance(fit.result, RESULTS) and int(fit.num_steps) > 0
    cost, cost_before = 0.0, 0.0
    for i, Fz in enumerate(LOADS):
        rms, worst, peaks = measured_errors(fit.params_at(Fz), fit.load, Fz, KAPPA, ALPHA)
        np.testing.assert_allclose(fit.rms_error[i], rms, rtol=1e-3, atol=1e-5)
        np.testing.assert_allclose(fit.max_error[i], worst, rtol=1e-3, atol=1e-5)
        np.testing.assert_allclose(fit.peak[i], peaks, rtol=1e-12)
        assert np.all(rms < RMS_BOUND), (Fz, rms)
        before, _, _ = measured_errors(init, UniformLoad(), Fz, KAPPA, ALPHA)
        cost += np.sum(rms**2) * (KAPPA.size + ALPHA.size)
        cost_before += np.sum(before**2) * (KAPPA.size + ALPHA.size)
    assert cost < 0.5 * cost_before, (cost, cost_before)


def test_characteristics_dispatch_to_their_formulas_in_the_report_signs():
    """`tire_characteristic`: the 1987 formula as written, a file's (from `TirFile`,
    `MFParams`, `MFTire` with its camber and pressure) at the file's slip angle -alpha; the
    defaults of the fit: the file's nominal load and 0.5, 1, 1.5 times it, slip angles of
    both signs."""
    k = jnp.array([-0.2, 0.0, 0.1, 0.1])
    a = jnp.array([0.05, -0.1, 0.0, 0.2])
    mf87 = bakker1987()
    np.testing.assert_array_equal(tire_characteristic(mf87).forces(k, a, 4000.0),
                                  combined_forces(mf87, k, a, 4000.0))
    assert isinstance(tire_characteristic(mf87), MagicFormula1987Characteristic)
    for tire, camber, p in ((SAMPLE, 0.0, None), (P, 0.0, None),
                            (MFTire(P, camber=0.03, pressure=2.1e5), 0.03, 2.1e5)):
        char = tire_characteristic(tire)
        assert isinstance(char, MFCharacteristic)
        got = np.asarray(char.forces(k, a, 3000.0))
        out = mf_evaluate(P, np.asarray(k), -np.asarray(a), 3000.0, camber, p)
        np.testing.assert_allclose(got, np.stack([out.Fx, out.Fy, out.Mz], -1), rtol=1e-13)
    char = tire_characteristic(P)
    assert char.nominal_load() == FZ0 and char.fit_loads() == (1900.0, 3800.0, 5700.0)
    # a narrow load range clips two of the three loads to one: that load is fitted once
    narrow = tire_characteristic(eqx.tree_at(lambda p: p.FZMAX, P, jnp.asarray(3000.0)))
    assert narrow.fit_loads() == (1900.0, 3000.0)
    alpha = np.asarray(char.slip_grid()[1])
    np.testing.assert_allclose(alpha, -alpha[::-1])
    with pytest.raises(TypeError, match="got str"):
        tire_characteristic("sample.tir")


# --- the command line ----------------------------------------------------------------------

def _vehsim(*args):
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(ROOT), os.environ.get("PYTHONPATH",
                                                                                 "")]))
    out = subprocess.run([sys.executable, "-m", "vehsim", *map(str, args)], capture_output=True,
                         text=True, env=env, timeout=600)
    return out.returncode, out.stdout, out.stderr


def test_show_json_is_what_the_formula_gives():
    """`vehsim tire show --json` (a real process): peak mu_x and mu_y are the maxima of
    |F_x0|/F_z and |F_y0|/F_z over dense slip grids, the cornering and slip stiffnesses
    central differences of F_y and F_x at zero slip, the ranges the file's."""
    rc, out, err = _vehsim("tire", "show", SAMPLE_PATH, "--json")
    assert rc == 0, err
    s = json.loads(out)
    assert s["version"] == "6.1" and s["nominal_load_N"] == FZ0 and s["load_N"] == FZ0
    kappa = np.linspace(-1.0, 1.0, 200001)
    fx = np.asarray(mf_evaluate(P, kappa, 0.0, FZ0, limits=False).Fx0) / FZ0
    np.testing.assert_allclose(s["peak_mu_x_driving"], fx.max(), rtol=1e-6)
    np.testing.assert_allclose(s["peak_mu_x_braking"], -fx.min(), rtol=1e-6)
    np.testing.assert_allclose(s["kappa_at_peak_mu_x_driving"], kappa[fx.argmax()], atol=2e-3)
    alpha = np.deg2rad(np.linspace(-30.0, 30.0, 200001))
    fy = np.abs(np.asarray(mf_evaluate(P, 0.0, alpha, FZ0, limits=False).Fy0)) / FZ0
    np.testing.assert_allclose(s["peak_mu_y"], fy.max(), rtol=1e-6)
    np.testing.assert_allclose(s["alpha_at_peak_mu_y_deg"], np.rad2deg(alpha[fy.argmax()]),
                               atol=0.05)
    h = 1e-6
    dfy = (mf_evaluate(P, 0.0, h, FZ0).Fy - mf_evaluate(P, 0.0, -h, FZ0).Fy) / (2 * h)
    dfx = (mf_evaluate(P, h, 0.0, FZ0).Fx - mf_evaluate(P, -h, 0.0, FZ0).Fx) / (2 * h)
    np.testing.assert_allclose(s["cornering_stiffness_N_per_rad"], dfy, rtol=1e-6)
    np.testing.assert_allclose(s["longitudinal_slip_stiffness_N"], dfx, rtol=1e-6)
    r = s["valid_ranges"]
    assert r["load_N"] == [SAMPLE.get("FZMIN"), SAMPLE.get("FZMAX")]
    assert r["slip_ratio"] == [SAMPLE.get("KPUMIN"), SAMPLE.get("KPUMAX")]
    np.testing.assert_allclose(r["camber_deg"], np.rad2deg([SAMPLE.get("CAMMIN"),
                                                            SAMPLE.get("CAMMAX")]))


def test_show_text_and_another_load(capsys):
    """The text names the version and states the values of the JSON at `--load`; a load
    below the file's FZMIN is evaluated, with a note saying so."""
    assert main(["tire", "show", str(SAMPLE_PATH), "--load", "5000"]) == 0
    text = capsys.readouterr().out
    assert "Magic Formula 6.1" in text and "at F_z = 5000 N" in text
    assert main(["tire", "show", str(SAMPLE_PATH), "--load", "5000", "--json"]) == 0
    captured = capsys.readouterr()
    s = json.loads(captured.out)
    assert "FZMIN" not in captured.err  # within the file's loads: no note
    assert f"peak mu_y             {s['peak_mu_y']:.4f}" in text
    assert f"cornering stiffness   {s['cornering_stiffness_N_per_rad']:.1f} N/rad" in text
    fy = np.abs(np.asarray(mf_evaluate(P, 0.0, np.deg2rad(np.linspace(-30, 30, 20001)),
                                       5000.0, limits=False).Fy0)) / 5000.0
    np.testing.assert_allclose(s["peak_mu_y"], fy.max(), rtol=1e-6)
    assert main(["tire", "show", str(SAMPLE_PATH), "--load", "100"]) == 0  # FZMIN is 190 N
    assert ("note: --load 100 N is below the file's FZMIN (190 N): the formula is evaluated "
            "there") in capsys.readouterr().err


def test_show_refuses_a_file_whose_formula_overflows_naming_its_largest_coefficient(
        tmp_path, capsys):
    """PDX1 = 1e308 (within a float, past what the formula can multiply): exit 2 naming the
    numbers that are not finite and the coefficient, in text and JSON; not NaN with exit 0."""
    text = Path(SAMPLE_PATH).read_text()
    line = next(i for i, t in enumerate(text.splitlines(), 1) if t.startswith("PDX1 "))
    bad = tmp_path / "huge.tir"
    bad.write_text("\n".join(t if not t.startswith("PDX1 ") else "PDX1 = 1e308"
                             for t in text.splitlines()) + "\n")
    for json_flag in ([], ["--json"]):
        assert main(["tire", "show", str(bad), *json_flag]) == 2
        captured = capsys.readouterr()
        assert captured.out == "", captured.out
        assert (f"{bad}: the Magic Formula is not finite at {FZ0:g} N (peak_mu_x_driving, "
                "peak_mu_x_braking, longitudinal_slip_stiffness_N)") in captured.err
        assert f"largest coefficient: PDX1 = 1e+308 (line {line})" in captured.err
    # plot and fit-lugre refuse it the same way, before drawing or compiling, writing nothing
    for command in (["plot", "--out", str(tmp_path / "c.png")],
                    ["fit-lugre", "--out", str(tmp_path / "f.json")]):
        assert main(["tire", command[0], str(bad), *command[1:]]) == 2
        err = capsys.readouterr().err
        assert f"{bad}: the Magic Formula is not finite at {FZ0:g} N" in err, err
        assert f"PDX1 = 1e+308 (line {line})" in err and "compiling" not in err, err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["huge.tir"]


def test_show_says_where_a_curve_has_no_peak_inside_the_search(tmp_path, capsys):
    """A lateral shape factor below 1 (PCY1 = 0.8) makes |F_y| rise all the way to the
    search's 30 deg: the summary says that its value is the largest at the edge, not a peak;
    the shipped file has its peaks inside."""
    text = SAMPLE_PATH.read_text().replace("PCY1                     = 1.4675",
                                           "PCY1                     = 0.8")
    flat = tmp_path / "flat.tir"
    flat.write_text(text)
    assert main(["tire", "show", str(flat), "--json"]) == 0
    s = json.loads(capsys.readouterr().out)
    assert s["peaks_at_search_edge"] == ["peak_mu_y"]
    assert abs(s["alpha_at_peak_mu_y_deg"]) == pytest.approx(30.0)
    assert main(["tire", "show", str(flat)]) == 0
    assert "for peak_mu_y: the value is the largest, at its edge" in capsys.readouterr().out
    assert main(["tire", "show", str(SAMPLE_PATH), "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["peaks_at_search_edge"] == []


def test_plot_draws_the_file_curves(tmp_path):
    """`vehsim tire plot`: a PNG; the curves it draws are `mf_evaluate`'s at the loads 0.5,
    1, 1.5 F_z0 and cambers -4, 0, 4 deg (file's axes), and the ellipse has the peaks."""
    from vehsim.cli.tire import tire_curves

    out = tmp_path / "fig.png"
    assert main(["tire", "plot", str(SAMPLE_PATH), "--out", str(out)]) == 0
    assert out.read_bytes()[:8] == PNG
    c = tire_curves(P)
    assert c["loads"] == [1900.0, 3800.0, 5700.0] and c["cambers_deg"] == [-4.0, 0.0, 4.0]
    alpha = np.deg2rad(c["alpha_deg"])
    for i, Fz in enumerate(c["loads"]):
        np.testing.assert_allclose(c["Fx"][i], mf_evaluate(P, c["kappa"], 0.0, Fz).Fx,
                                   rtol=1e-12)
        np.testing.assert_allclose(c["Mz"][i], mf_evaluate(P, 0.0, alpha, Fz).Mz, rtol=1e-12)
    np.testing.assert_allclose(c["Fy_camber"][0],
                               mf_evaluate(P, 0.0, alpha, FZ0, math.radians(-4.0)).Fy,
                               rtol=1e-12)
    fx, fy = c["combined"]["alpha = +/-4 deg"]
    assert np.nanmax(np.hypot(fx / c["ellipse"][0], fy / c["ellipse"][1])) < 1.05


def test_fit_lugre_writes_table_json_and_figure(tmp_path, capsys):
    """`vehsim tire fit-lugre` (one load, 3 steps: far from the optimum, so the solver's
    `nonlinear_max_steps_reached` stands, MINPACK's numbers above their tolerances, exit
    1): the JSON's errors in N are its relative errors times each curve's peak, and the
    peaks are those of `mf_evaluate` on the JSON's grid at the file's slip angle -alpha;
    the printed table has its numbers; the figure beside it; v_s and gamma held."""
    out = tmp_path / "fit.json"
    rc = main(["tire", "fit-lugre", str(SAMPLE_PATH), "--out", str(out), "--loads", "3800",
               "--max-steps", "3"])
    captured = capsys.readouterr()
    printed = captured.out
    r = json.loads(out.read_text())
    assert rc == 1 and r["status"] == r["solver_status"] == "nonlinear_max_steps_reached"
    assert r["message"].startswith("Levenberg-Marquardt stopped after 3 steps")
    said = r["message"].replace("`max_steps`", "--max-steps")  # the option, not the setting
    assert "increase `max_steps`" in r["message"] and "increase --max-steps" in said
    assert said in printed and said in captured.err
    assert r["gradient_cosine"] > 1e-6 and r["predicted_relative_reduction"] > 1e-6
    assert r["held"] == ["v_s", "gamma"]
    assert (r["lugre"]["v_s_m_per_s"], r["lugre"]["gamma"]) == (3.0, 0.7)
    assert (tmp_path / "fit.png").read_bytes()[:8] == PNG
    assert r["loads_N"] == [3800.0] and r["num_steps"] == 3 and r["version"] == "6.1"
    assert {"sigma0_per_m", "mu_k", "mu_s", "v_s_m_per_s", "L0_m", "patch_exponent",
            "load_weights"} <= set(r["lugre"])
    kappa, alpha = np.array(r["slip_ratio_grid"]), np.deg2rad(r["slip_angle_grid_deg"])
    peaks = [np.abs(c).max() for c in mf_pure_report_signs(kappa, alpha, 3800.0)]
    row = r["errors"][0]
    for q, peak, u in zip(("F_x", "F_y", "M_z"), peaks, ("N", "N", "N_m")):
        np.testing.assert_allclose(row[q][f"peak_{u}"], peak, rtol=1e-12)
        np.testing.assert_allclose(row[q][f"rms_{u}"], row[q]["rms_relative_to_peak"] * peak,
                                   rtol=1e-12)
        cell = (f"{row[q][f'max_{u}']:.1f} "
                f"({100 * row[q]['max_relative_to_peak']:.1f} %)")
        assert cell in printed
    assert r["errors"][0]["F_y"]["rms_relative_to_peak"] < \
        r["initial_errors"][0]["F_y"]["rms_relative_to_peak"]


def _bad_files(tmp_path):
    malformed = tmp_path / "malformed.tir"
    malformed.write_text(SAMPLE_PATH.read_text(encoding="latin-1").replace(
        "PCY1                     = ", "PCY1                     = oops ! "), encoding="latin-1")
    csv = tmp_path / "data.csv"
    csv.write_text("t,v\n0,1\n")
    return {"missing": (tmp_path / "nope.tir", "no such file"),
            "folder": (tmp_path, "not a file"),
            "not a tir": (csv, "text before the first section"),
            "malformed": (malformed, "PCY1")}


@pytest.mark.parametrize("command", [["show"], ["plot"], ["fit-lugre"]])
def test_bad_files_exit_2_naming_the_file_and_write_nothing(tmp_path, capsys, command):
    """A missing file, a folder, a CSV and a .tir with a bad value: exit status 2, the file
    (and for the bad value its line and key) named, nothing written."""
    outdir = tmp_path / "out"
    outdir.mkdir()
    out = outdir / ("fig.png" if command == ["plot"] else "fit.json")
    extra = [] if command == ["show"] else ["--out", str(out)]
    for name, (path, words) in _bad_files(tmp_path).items():
        assert main(["tire", *command, str(path), *extra]) == 2, name
        err = capsys.readouterr().err
        assert str(path) in err and words in err, (name, err)
        if name == "malformed":
            line = next(i for i, t in enumerate(path.read_text().splitlines(), 1)
                        if t.startswith("PCY1"))
            assert f"{path}:{line}: PCY1:" in err
        assert list(outdir.iterdir()) == [], name


def test_bad_options_and_a_missing_file_in_a_real_process(tmp_path, capsys):
    """Bad option values exit 2 naming the option before anything is written; a missing
    file in a real process: exit 2, one line naming it, no traceback."""
    out = tmp_path / "fit.json"
    for args in (["--loads", "3800,-1"], ["--loads", "3800,x"], ["--loads", "3_800"],
                 ["--speed", "0"],
                 ["--max-steps", "0"], ["--out", str(tmp_path / "fit.png")]):
        assert main(["tire", "fit-lugre", str(SAMPLE_PATH), "--out", str(out), *args]) == 2
        assert args[0] in capsys.readouterr().err
    assert main(["tire", "show", str(SAMPLE_PATH), "--load", "-5"]) == 2
    assert "--load" in capsys.readouterr().err
    assert list(tmp_path.iterdir()) == []
    rc, out_text, err = _vehsim("tire", "show", tmp_path / "nope.tir")
    assert rc == 2 and "Traceback" not in err and f"{tmp_path / 'nope.tir'}: no such file" in err


@pytest.mark.parametrize("args, message", [
    (["show", "{tir}", "--load", "1e300"], "--load: 1e+300 N is outside the file's load range "
                                           "(0, 8550] N (up to FZMAX)"),
    (["fit-lugre", "{tir}", "--loads", "10,20,30"], "--loads: 10 N is outside the file's load "
                                                    "range [190, 8550] N (FZMIN, FZMAX)"),
    (["fit-lugre", "{tir}", "--loads", "3800,2000,3800"], "--loads: 3800 N given more than "
                                                          "once; the loads fitted together must "
                                                          "differ"),
])
def test_loads_outside_the_files_range_are_refused(args, message, tmp_path, capsys):
    """The summary and the fit only at loads the file is valid for (its FZMIN, FZMAX): a load
    of 1e300 N printed NaN, loads below FZMIN were fitted (exit 0)."""
    tir = SAMPLE_PATH
    rc = main(["tire", *[a.format(tir=tir) for a in args], "--out", str(tmp_path / "f.json")]
              if args[0] == "fit-lugre" else ["tire", *[a.format(tir=tir) for a in args]])
    assert rc == 2
    assert message in capsys.readouterr().err
    assert not any(tmp_path.iterdir())
