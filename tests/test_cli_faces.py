"""The command line as a user runs it: ``python -m vehsim`` in a subprocess at its smallest
sizes, checking what each command writes (the JSON fields, the files) and its exit status,
on good input and bad. One subprocess per command; the optimise run shares its worker, and
the compiled primitive, with the in-process corner90 tests it is compared with."""

import importlib
import json
import os
import re
import subprocess
import sys
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from vehsim import reproduce
from vehsim.identify.braking import shipped_brakings
from vehsim.identify.parameters import PARAMETER_NAMES
from vehsim.params import table3
from vehsim.robot.scoring import LETTERS
from vehsim.tire.steady_state import braking_mu_uniform


ROOT = Path(__file__).parent.parent
PNG = b"\x89PNG\r\n\x1a\n"


def _vehsim(*args, timeout=900):
    """``python -m vehsim ARGS``: (exit status, stdout, stderr)."""
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(ROOT), os.environ.get("PYTHONPATH",
                                                                                 "")]))
    out = subprocess.run([sys.executable, "-m", "vehsim", *map(str, args)], capture_output=True,
                         text=True, env=env, timeout=timeout)
    return out.returncode, out.stdout, out.stderr


def _is_png(path: Path) -> bool:
    return path.is_file() and path.read_bytes()[:8] == PNG


def test_fit_writes_parameters_errors_and_figure(tmp_path):
    """`vehsim fit` on two shipped brakings with a third held out (fitted kappa0, one start):
    exit 0, fit.json with every parameter, standard errors for the free ones, the status,
    and a held-out error within the README's claim (1.5 % of the peak force, here < 3 %);
    fit.png. A missing file: exit 2, the path named."""
    files = shipped_brakings()
    rc, _, err = _vehsim("fit", files["braking_1"], files["braking_2"], "--validate",
                         files["braking_3"], "--out", tmp_path, "--starts", 1,
                         "--only-fitted-kappa0")
    assert rc == 0, err
    data = json.loads((tmp_path / "fit.json").read_text())
    assert (data["mode"], data["train"], data["validate"]) == (
        "open_loop", ["braking_1", "braking_2"], ["braking_3"])
    fit = data["fits"]["kappa0 fitted"]
    assert fit["status"] == "successful" and isinstance(fit["message"], str)
    assert set(PARAMETER_NAMES) <= set(fit["parameters"])
    assert set(fit["std_errors"]) == set(fit["free"]) <= set(PARAMETER_NAMES)
    assert all(v > 0 for v in fit["std_errors"].values())
    held_out = fit["validation_errors"]["braking_3"]
    assert 0 < held_out["rms_error_rel_peak"] < 0.03
    assert data["units"]["fits.kappa0 fitted.parameters.theta"] == "1"  # LuGre's, not a pitch
    assert data["units"]["fits.kappa0 fitted.parameters.sigma0"] == "1/m"
    assert _is_png(tmp_path / "fit.png")
    rc, _, err = _vehsim("fit", tmp_path / "no_such.csv", "--out", tmp_path / "x")
    assert rc == 2 and "no_such.csv" in err and "vehsim: error:" in err


@pytest.mark.xdist_group("corner90_min_time")
def test_optimise_writes_the_primitive_the_library_solves(tmp_path):
    """`vehsim optimise corner90 --segments 30`: exit 0, the solution JSON (status, t_f
    equal to the library's primitive on the same grid, the point-mass bound below it,
    violations, states and inputs at every node) and the figure. Too few segments: exit 2,
    naming the option. Too few iterations: exit 1, the residuals on the status line."""
    from optimal_cache import M, corner90_min_time

    from vehsim.optimal.primitives import point_mass_bound

    rc, _, err = _vehsim("optimise", "corner90", "--segments", M, "--quiet", "--out", tmp_path)
    assert rc == 0, err
    rec = json.loads((tmp_path / "corner90_min-time.json").read_text())
    assert (rec["road"], rec["objective"], rec["status"]) == ("corner90", "min-time",
                                                              "successful")
    np.testing.assert_allclose(rec["t_f"], float(corner90_min_time().t_f), rtol=1e-9)
    bound = point_mass_bound("corner90", num_stages=M, steps_per_stage=1)
    np.testing.assert_allclose(rec["point_mass_t_f"], float(bound.t_f), rtol=1e-9)
    assert rec["point_mass_t_f"] < rec["t_f"] and rec["max_corridor_violation"] <= 1e-3
    assert set(rec["violations"]) >= {"corridor", "boundary", "defects"}
    assert (rec["steps_per_stage"], rec["corner_clearance"], rec["interior_points"]) == (
        1, True, 0)
    assert rec["max_corridor_violation_between_nodes"] < 0.01  # the corner clearance
    assert len(rec["t"]) == len(rec["states"]["x"]) == len(rec["inputs"]["delta"]) == M + 1
    assert (rec["units"]["t_f"], rec["units"]["states.vx"],
            rec["units"]["max_corridor_violation_between_nodes"]) == ("s", "m/s", "m")
    assert _is_png(tmp_path / "corner90_min-time.png")
    rc, _, err = _vehsim("optimise", "corner90", "--segments", 1, "--out", tmp_path / "x")
    assert rc == 2 and "--segments" in err
    # stopped short of the optimum: exit 1, its residuals on the status line
    rc, _, err = _vehsim("optimise", "corner90", "--segments", M, "--max-iter", 3, "--quiet",
                         "--out", tmp_path / "capped")
    assert rc == 1 and "NOT CONVERGED: final residuals inf_pr" in err, err
    assert "vehsim optimise: ip_max_iterations: " in err and "Increase --max-iter," in err, err


@pytest.mark.xdist_group("corner90_min_time")  # its optimal section: the tests' primitive
def test_reproduce_every_section_at_its_smallest(tmp_path):
    """`vehsim reproduce --tiny`: every section runs (exit 0); report.md has each section's
    title and every figure it links exists as a PNG; results.json has each section's time
    and a number from each. An unknown section: exit 2, the sections listed."""
    rc, _, err = _vehsim("reproduce", "--tiny", "--out", tmp_path)
    assert rc == 0, err
    report = (tmp_path / "report.md").read_text()
    results = json.loads((tmp_path / "results.json").read_text())
    assert results["units"]["fig13.max_Fx_alpha0_N"] == "N"  # the block every JSON ends with
    for name in reproduce.SECTIONS:
        assert f"## {importlib.import_module(name).TITLE}" in report, name
        assert results[f"{name}.wall_time_s"] > 0, name
    figures = re.findall(r"\]\(([^)]+\.png)\)", report)
    assert len(figures) >= 12 and all(_is_png(tmp_path / f) for f in figures), figures
    assert set(results["robot.table2.ours"]) == {f"{c}-{s}" for c in range(1, 9)
                                                 for s in ("I", "II")}
    assert all(len(v) == 4 for v in results["robot.table2.ours"].values())
    assert 0 < results["identify.kappa0 fitted.held_out_rms_rel_peak"] < 0.03
    assert all(set(v) <= set(LETTERS) for v in results["robot.table2.ours"].values())
    assert results["corner90_min-time"]["status"] == "successful"
    # Fig. 7a's peak at 20 m/s: the largest braking friction of eq. 19 on its slip grid
    s = jnp.linspace(-1.0, 0.0, 201)
    mu = jax.jit(jax.vmap(lambda x: braking_mu_uniform(table3(), x, 20.0)))(s)
    np.testing.assert_allclose(results["fig7a_peaks"]["20"]["mu_peak"], -float(mu.min()),
                               rtol=1e-12)
    assert results["fig13.max_Fx_alpha0_N"] > 0
    assert results["vehicle.step_steer.final_speed_m_s"] > 0
    rc, _, err = _vehsim("reproduce", "--out", tmp_path / "x", "--only", "no-such-section")
    assert rc == 2 and "no section matches" in err and "optimal" in err


def test_brake_writes_the_braking_against_its_limits_and_caches_what_it_compiled(tmp_path):
    """`vehsim brake` on wet asphalt from 20 m/s: exit 0, brake.json with the distances, the
    limits (the hardware's above the tire's, the run above both) and the estimate;
    brake.png; the compiled programs written to the cache folder. Run again with
    ``--no-compilation-cache``: the same record, and its cache folder stays empty. An unknown
    surface: exit 2, the known ones named."""
    env = {k: v for k, v in os.environ.items() if k != "JAX_COMPILATION_CACHE_DIR"}
    env["PYTHONPATH"] = os.pathsep.join([str(ROOT), os.environ.get("PYTHONPATH", "")])
    records = []
    for flags, cache in (((), tmp_path / "cache"), (("--no-compilation-cache",),
                                                      tmp_path / "no-cache")):
        out = subprocess.run([sys.executable, "-m", "vehsim", *flags, "brake", "--surface",
                              "wet_asphalt", "--speed", "20", "--out", tmp_path / cache.name],
                             capture_output=True, text=True, timeout=900,
                             env=env | {"VEHSIM_CACHE_DIR": str(cache / "jax")})
        assert out.returncode == 0, out.stderr
        records.append(json.loads((tmp_path / cache.name / "brake.json").read_text()))
        assert _is_png(tmp_path / cache.name / "brake.png")
    cached, uncached = tmp_path / "cache" / "jax", tmp_path / "no-cache" / "jax"
    assert any(p.name.startswith("jit_closed_loop_grid") for p in cached.iterdir())
    assert not uncached.exists() or not any(uncached.iterdir())
    rec = records[0]
    assert rec == records[1]
    assert (rec["units"]["stopping_distance_m"], rec["units"]["theta_estimate"]) == ("m", "1")
    assert (rec["surface"], rec["controller"], rec["status"]) == ("wet_asphalt", "estimate",
                                                                  "successful")
    assert rec["bound_distance_m"] < rec["actuated_bound_distance_m"] < rec[
        "stopping_distance_m"] < rec["locked_wheel"]["stopping_distance_m"]
    assert rec["distance_over_bound"] == pytest.approx(
        rec["stopping_distance_m"] / rec["bound_distance_m"], rel=1e-12)
    assert rec["distance_over_bound"] <= 1.03
    assert rec["theta_true"] > 0 and rec["theta_settling_time_s"] < 0.5
    rc, _, err = _vehsim("brake", "--surface", "gravel", "--out", tmp_path / "x")
    assert rc == 2 and "gravel" in err and "wet_asphalt" in err
    # a figure that cannot be written (a folder in its place): exit 2, and no record without it
    (tmp_path / "blocked" / "brake.png").mkdir(parents=True)
    out = subprocess.run([sys.executable, "-m", "vehsim", "brake", "--surface", "wet_asphalt",
                          "--speed", "20", "--out", tmp_path / "blocked"],
                         capture_output=True, text=True, timeout=900,
                         env=env | {"VEHSIM_CACHE_DIR": str(tmp_path / "cache" / "jax")})
    assert out.returncode == 2 and out.stderr.strip().endswith(
        f"Is a directory: '{tmp_path / 'blocked' / 'brake.png'}'"), out.stderr
    assert sorted(p.name for p in (tmp_path / "blocked").iterdir()) == ["brake.png"]
