"""The Magic Formula 5.2 / 6.1 / 6.2 of the tyre property files (vehsim.tire.mf6).

Held to a transcription other than its own (CommonRoad's PAC2002), to values worked out here
by hand from the published equations for the terms CommonRoad lacks, to the symmetries and
limits the formulas imply, to finite differences (forward and reverse, also at zero slip and
zero speed), and driven by the vehicles as every other tire."""

import math
import types
import warnings

import diffrax
import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from helpers import fd_grad

from vehsim import (
    HalfCar,
    MFLongitudinalTire,
    MFParams,
    MFTire,
    QuarterCar,
    RelaxedMFTire,
    mf_evaluate,
    mf_forces,
    mf_relaxation_lengths,
    mf_summary,
    rally_gravel,
    simulate,
    simulate_quarter_car,
)
from vehsim.tire.mf6 import FIELD_NAMES
from vehsim.tire.tir import format_tir, parse_tir, read_tir, shipped_tires


SAMPLE = read_tir(shipped_tires()["sample_185_80R14_mf61"])
FZ0 = 3800.0


def params_of(tir, **changes) -> MFParams:
    """MFParams of `tir` with keys changed (written and read again, as a file would be)."""
    return MFParams.from_tir(parse_tir(format_tir(tir.replace(**changes))))


# --- CommonRoad's PAC2002 -------------------------------------------------------------------

def commonroad_forces(P: MFParams, kappa, alpha, gamma, Fz):
    """CommonRoad's PAC2002 (vehiclemodels.utils.tire_model, commonroad-vehicle-models 3.0.2)
    with `P`'s coefficients mapped onto its names: (Fx0, Fy0, Fx, Fy)."""
    cr = pytest.importorskip("vehiclemodels.utils.tire_model")
    g = math.sin(gamma)  # the file's gamma* = sin(gamma) (4.E4): CommonRoad takes gamma
    ta = math.tan(alpha)  # alpha* = tan(alpha) (4.E3): CommonRoad takes alpha
    f = {k: float(getattr(P, k)) for k in FIELD_NAMES}
    p = types.SimpleNamespace(
        p_cx1=f["PCX1"], p_dx1=f["PDX1"], p_dx3=f["PDX3"], p_ex1=f["PEX1"], p_kx1=f["PKX1"],
        p_hx1=f["PHX1"], p_vx1=f["PVX1"],
        p_cy1=f["PCY1"], p_dy1=f["PDY1"], p_dy3=f["PDY3"], p_ey1=f["PEY1"],
        # cornering stiffness PKY1*Fz: the load-dependent form at its load, camber included
        p_ky1=f["PKY1"] * math.sin(f["PKY4"] * math.atan(Fz / (f["PKY2"] * FZ0)))
        * FZ0 / Fz * (1 - f["PKY3"] * abs(g)),
        p_hy1=f["PHY1"], p_hy3=f["PHY3"], p_vy1=f["PVY1"], p_vy3=f["PVY3"],
        r_bx1=f["RBX1"], r_bx2=f["RBX2"], r_cx1=f["RCX1"], r_ex1=f["REX1"], r_hx1=f["RHX1"],
        r_by1=f["RBY1"], r_by2=f["RBY2"], r_by3=f["RBY3"], r_cy1=f["RCY1"], r_ey1=f["REY1"],
        r_hy1=f["RHY1"], r_vy1=f["RVY1"], r_vy3=f["RVY3"], r_vy4=f["RVY4"], r_vy5=f["RVY5"],
        r_vy6=f["RVY6"])
    fx0 = cr.formula_longitudinal(-kappa, g, Fz, p)  # its slip has the opposite sign
    fy0, mu_y = cr.formula_lateral(ta, g, Fz, p)
    fx = cr.formula_longitudinal_comb(kappa, ta, fx0, p)
    fy = cr.formula_lateral_comb(kappa, ta, g, mu_y, Fz, fy0, p)
    return np.array([fx0, fy0, fx, fy])


NEUTRAL = dict(PVX1=0.0, PVX2=0.0, PEX4=0.0, PEY3=0.0, PEY4=0.0)


@pytest.mark.parametrize("version,gamma", [(52, 0.0), (52, 0.03), (61, 0.0)])
def test_agrees_with_commonroad_pac2002_once_its_departures_are_neutralised(version, gamma):
    """CommonRoad's PAC2002 is a simplified MF 5.2; each departure is neutralised by
    equivalent parameters or inputs, never copied:

    - cornering stiffness PKY1*Fz instead of PKY1 Fz0' sin(PKY4 atan(Fz/(PKY2 Fz0')))
      (1 - PKY3|gamma|): its p_ky1 is that value divided by Fz, at the load compared;
    - lateral shifts multiplied by sgn(gamma) (PHY1, PVY1 vanish at zero camber, flip sign
      at negative camber): compared at gamma > 0, where sgn = 1, and at gamma = 0 with
      PHY1 = PVY1 = 0;
    - no curvature asymmetry PEY3, PEY4, and no PEX4: set to 0;
    - the longitudinal vertical shift added inside the sine: PVX1 = PVX2 = 0;
    - nominal load only (no PDX2, PKX2, PEX2, ..., RHY2 terms): compared at Fz = FNOMIN,
      where dfz = 0 and they vanish;
    - scaling factors 1, no pressure, no M_z: the sample's scalings are 1, pressure is
      nominal, M_z is checked by hand below;
    - inputs: it takes alpha and gamma where the file's formulas take tan(alpha) and
      sin(gamma) (4.E3, 4.E4), and its longitudinal slip with the opposite sign: we pass
      the equivalent inputs.

    Versions 5.2 (PAC2002, with a PHY3 camber shift) and 6.1 (camber through PKY6, PKY7,
    which CommonRoad lacks: compared at gamma = 0 only)."""
    changes = dict(NEUTRAL, FITTYP=version, PHY3=0.037561 if version == 52 else 0.0)
    if gamma == 0.0:
        changes.update(PHY1=0.0, PVY1=0.0)
    P = params_of(SAMPLE, **changes)
    worst = 0.0
    for kappa in (-0.3, -0.08, -0.01, 0.0, 0.02, 0.1, 0.4):
        for alpha in (-0.25, -0.06, 0.0, 0.01, 0.08, 0.3):
            out = mf_evaluate(P, kappa, alpha, FZ0, gamma, limits=False)
            ours = np.array([out.Fx0, out.Fy0, out.Fx, out.Fy], dtype=float)
            theirs = commonroad_forces(P, kappa, alpha, gamma, FZ0)
            np.testing.assert_allclose(ours, theirs, rtol=1e-10, atol=1e-8)
            worst = max(worst, float(np.max(np.abs(ours - theirs))))
    print(f"largest difference to CommonRoad: {worst:.2e} N")


def test_commonroad_departures_are_real():
    """Without the neutralisations the two differ (so the test above tests something):
    CommonRoad's cornering stiffness PKY1*Fz is 1/sin(2 atan(1/PKY2)) times the file's at
    nominal load (1.05 for the sample's PKY2 = 1.3856; 1.8 for PKY2 = 3.378)."""
    P = params_of(SAMPLE, FITTYP=52)
    cr = pytest.importorskip("vehiclemodels.utils.tire_model")
    p = types.SimpleNamespace(p_cy1=float(P.PCY1), p_dy1=float(P.PDY1), p_dy3=0.0,
                              p_ey1=float(P.PEY1), p_ky1=float(P.PKY1), p_hy1=0.0, p_hy3=0.0,
                              p_vy1=0.0, p_vy3=0.0)
    fy_cr = cr.formula_lateral(0.001, 0.0, FZ0, p)[0]
    out = mf_evaluate(P, 0.0, math.atan(0.001), FZ0, limits=False)
    fy = float(out.Fy0) - float(mf_evaluate(P, 0.0, 0.0, FZ0).Fy0)
    ratio = 1.0 / math.sin(2.0 * math.atan(1.0 / float(P.PKY2)))
    np.testing.assert_allclose(fy_cr / fy, ratio, rtol=2e-3)
    assert ratio > 1.04


# --- hand-computed values from the published equations ----------------------------------------

SCALED = dict(
    PPX1=-0.35, PPX2=0.38, PPX3=-0.1, PPX4=0.06, PPY1=-0.65, PPY2=-0.8, PPY3=-0.2, PPY4=0.2,
    PPY5=-0.1, PPZ1=-0.2, PPZ2=0.3, PPMX1=0.1, QDZ10=0.1, QDZ11=0.2, PEY5=0.5, PKY5=0.3,
    PKY4=1.9, RBX3=1.0, RBY4=1.0, QSY5=0.001, QSY6=0.002, QSY7=0.9, QSY8=-0.4, QSX4=0.1,
    QSX5=0.2,
    QSX6=1.5, QSX7=0.3, QSX8=0.2, QSX9=0.4, QSX10=0.05, QSX11=0.3, QSX12=0.2, QSX13=0.01,
    QSX14=0.02, QSX1=0.001, QSX2=0.5, QSX3=0.02, QSY2=0.01, QSY3=0.002, QSY4=0.0003,
    LFZO=1.1, LMUX=0.9, LMUY=0.95, LKX=1.1, LKY=0.9, LCX=1.02, LCY=0.98, LEX=0.9, LEY=1.1,
    LHX=1.2, LHY=0.8, LVX=1.3, LVY=0.7, LKYC=1.2, LKZC=0.8, LTR=1.1, LRES=0.9, LXAL=1.1,
    LYKA=0.9, LVYKA=1.2, LS=1.1, LMX=1.1, LVMX=0.9, LMY=1.05)


def hand_computed(c, kappa, alpha, gamma, Fz, p):
    """MF 6.1 at one point, in plain Python from Pacejka (2012) 4.E1-4.E78 with the paper's
    trail camber terms (A58, A60), M_x as 4.E69 plus q_sx12..14 and M_y as the paper's A48
    (at V = LONGVL): each line is one published equation."""
    sgn = lambda x: -1.0 if x < 0 else (1.0 if x > 0 else 0.0)  # noqa: E731
    mf = lambda B, C, D, E, x: D * math.sin(C * math.atan(B * x - E * (B * x - math.atan(B * x))))  # noqa: E501, E731
    G = lambda B, C, E, x: math.cos(C * math.atan(B * x - E * (B * x - math.atan(B * x))))  # noqa: E731
    fz0p = c["LFZO"] * c["FNOMIN"]  # 4.E1
    dfz = (Fz - fz0p) / fz0p  # 4.E2a
    dpi = (p - c["NOMPRES"]) / c["NOMPRES"]  # 4.E2b
    a = math.tan(alpha)  # 4.E3
    g = math.sin(gamma)  # 4.E4
    R0 = c["UNLOADED_RADIUS"]
    # pure longitudinal 4.E9-4.E18
    Cx = c["PCX1"] * c["LCX"]
    mux = (c["PDX1"] + c["PDX2"] * dfz) * (1 + c["PPX3"] * dpi + c["PPX4"] * dpi**2) \
        * (1 - c["PDX3"] * g**2) * c["LMUX"]
    Dx = mux * Fz
    Kx = Fz * (c["PKX1"] + c["PKX2"] * dfz) * math.exp(c["PKX3"] * dfz) \
        * (1 + c["PPX1"] * dpi + c["PPX2"] * dpi**2) * c["LKX"]
    Bx = Kx / (Cx * Dx)
    SHx = (c["PHX1"] + c["PHX2"] * dfz) * c["LHX"]
    SVx = Fz * (c["PVX1"] + c["PVX2"] * dfz) * c["LVX"] * c["LMUX"]
    kx = kappa + SHx
    Ex = (c["PEX1"] + c["PEX2"] * dfz + c["PEX3"] * dfz**2) * (1 - c["PEX4"] * sgn(kx)) * c["LEX"]
    Fx0 = mf(Bx, Cx, Dx, Ex, kx) + SVx

    def fy0(g):  # 4.E19-4.E30
        Kya = c["PKY1"] * fz0p * (1 + c["PPY1"] * dpi) * (1 - c["PKY3"] * abs(g)) * math.sin(
            c["PKY4"] * math.atan(Fz / fz0p / ((c["PKY2"] + c["PKY5"] * g**2)
                                               * (1 + c["PPY2"] * dpi)))) * c["LKY"]
        SVyg = Fz * (c["PVY3"] + c["PVY4"] * dfz) * g * c["LKYC"] * c["LMUY"]
        Kyg0 = Fz * (c["PKY6"] + c["PKY7"] * dfz) * (1 + c["PPY5"] * dpi) * c["LKYC"]
        SHy = (c["PHY1"] + c["PHY2"] * dfz) * c["LHY"] + (Kyg0 * g - SVyg) / Kya
        SVy = Fz * (c["PVY1"] + c["PVY2"] * dfz) * c["LVY"] * c["LMUY"] + SVyg
        ay = a + SHy
        Cy = c["PCY1"] * c["LCY"]
        muy = (c["PDY1"] + c["PDY2"] * dfz) * (1 + c["PPY3"] * dpi + c["PPY4"] * dpi**2) \
            * (1 - c["PDY3"] * g**2) * c["LMUY"]
        Dy = muy * Fz
        Ey = (c["PEY1"] + c["PEY2"] * dfz) * (1 + c["PEY5"] * g**2
                                              - (c["PEY3"] + c["PEY4"] * g) * sgn(ay)) * c["LEY"]
        By = Kya / (Cy * Dy)
        return mf(By, Cy, Dy, Ey, ay) + SVy, muy, Kya, By, Cy, SHy, SVy

    Fy0, muy, Kya, By, Cy, SHy, SVy = fy0(g)
    Fy0_g0 = fy0(0.0)[0]
    # aligning moment 4.E31-4.E47 (A58, A60)
    SHt = c["QHZ1"] + c["QHZ2"] * dfz + (c["QHZ3"] + c["QHZ4"] * dfz) * g
    ar = a + SHy + SVy / Kya
    at = a + SHt
    Dt = (c["QDZ1"] + c["QDZ2"] * dfz) * (1 - c["PPZ1"] * dpi) * (1 + c["QDZ3"] * g
                                                                  + c["QDZ4"] * g**2) \
        * Fz * (R0 / fz0p) * c["LTR"]
    Bt = (c["QBZ1"] + c["QBZ2"] * dfz + c["QBZ3"] * dfz**2) * (1 + c["QBZ4"] * g
                                                               + c["QBZ5"] * abs(g)) \
        * c["LKY"] / c["LMUY"]
    Ct = c["QCZ1"]
    Et = (c["QEZ1"] + c["QEZ2"] * dfz + c["QEZ3"] * dfz**2) * (
        1 + (c["QEZ4"] + c["QEZ5"] * g) * (2 / math.pi) * math.atan(Bt * Ct * at))
    Dr = Fz * R0 * ((c["QDZ6"] + c["QDZ7"] * dfz) * c["LRES"]
                    + ((c["QDZ8"] + c["QDZ9"] * dfz) * (1 + c["PPZ2"] * dpi)
                       + (c["QDZ10"] + c["QDZ11"] * dfz) * abs(g)) * g * c["LKZC"]) * c["LMUY"]
    Br = c["QBZ9"] * c["LKY"] / c["LMUY"] + c["QBZ10"] * By * Cy
    t0 = Dt * G(Bt, Ct, Et, at) * math.cos(alpha)
    Mz0 = -t0 * Fy0_g0 + Dr * math.cos(math.atan(Br * ar)) * math.cos(alpha)
    # combined 4.E50-4.E67
    Bxa = (c["RBX1"] + c["RBX3"] * g**2) * math.cos(math.atan(c["RBX2"] * kappa)) * c["LXAL"]
    Exa = c["REX1"] + c["REX2"] * dfz
    Gxa = G(Bxa, c["RCX1"], Exa, a + c["RHX1"]) / G(Bxa, c["RCX1"], Exa, c["RHX1"])
    Fx = Gxa * Fx0

    def gyk(g):
        Byk = (c["RBY1"] + c["RBY4"] * g**2) * math.cos(math.atan(c["RBY2"] * (a - c["RBY3"]))) \
            * c["LYKA"]
        Eyk = c["REY1"] + c["REY2"] * dfz
        SHyk = c["RHY1"] + c["RHY2"] * dfz
        return G(Byk, c["RCY1"], Eyk, kappa + SHyk) / G(Byk, c["RCY1"], Eyk, SHyk)

    DVyk = muy * Fz * (c["RVY1"] + c["RVY2"] * dfz + c["RVY3"] * g) * math.cos(
        math.atan(c["RVY4"] * a))
    SVyk = DVyk * math.sin(c["RVY5"] * math.atan(c["RVY6"] * kappa)) * c["LVYKA"]
    Fy = gyk(g) * Fy0 + SVyk
    # combined aligning moment 4.E71-4.E78
    ratio = (Kx / Kya) ** 2 * kappa**2
    at_eq = math.sqrt(at**2 + ratio)
    ar_eq = math.sqrt(ar**2 + ratio)
    t = Dt * G(Bt, Ct, Et, at_eq) * math.cos(alpha)
    Mzr = Dr * math.cos(math.atan(Br * ar_eq)) * math.cos(alpha)
    s = R0 * (c["SSZ1"] + c["SSZ2"] * Fy / fz0p + (c["SSZ3"] + c["SSZ4"] * dfz) * g) * c["LS"]
    Mz = -t * gyk(0.0) * Fy0_g0 + Mzr + s * Fx
    # M_x (4.E69 + q_sx12..14), M_y (A48) at V = LONGVL
    F0 = c["FNOMIN"]
    Mx = R0 * Fz * c["LMX"] * (
        c["QSX1"] * c["LVMX"] - c["QSX2"] * gamma * (1 + c["PPMX1"] * dpi)
        - c["QSX12"] * gamma * abs(gamma) + c["QSX3"] * Fy / F0
        + c["QSX4"] * math.cos(c["QSX5"] * math.atan((c["QSX6"] * Fz / F0) ** 2))
        * math.sin(c["QSX7"] * gamma + c["QSX8"] * math.atan(c["QSX9"] * Fy / F0))
        + c["QSX10"] * math.atan(c["QSX11"] * Fz / F0) * gamma) \
        + R0 * Fy * c["LMX"] * (c["QSX13"] + c["QSX14"] * abs(gamma))
    My = -R0 * F0 * c["LMY"] * (c["QSY1"] + c["QSY2"] * Fx / F0 + c["QSY3"] + c["QSY4"]
                                + (c["QSY5"] + c["QSY6"] * Fz / F0) * gamma**2) \
        * (Fz / F0) ** c["QSY7"] * (p / c["NOMPRES"]) ** c["QSY8"]
    return dict(Fx0=Fx0, Fy0=Fy0, Mz0=Mz0, Fx=Fx, Fy=Fy, Mz=Mz, Mx=Mx, My=My, Kxk=Kx, Kya=Kya)


@pytest.mark.parametrize("point", [(0.06, -0.07, 0.04, 5200.0, 2.1e5),
                                   (-0.15, 0.12, -0.05, 2500.0, 1.7e5),
                                   (0.0, 0.0, 0.0, 4180.0, 1.9e5)])
def test_load_scaling_pressure_camber_and_moments_match_hand_computed_values(point):
    """The terms CommonRoad lacks (load dependence, every scaling factor, pressure,
    camber, M_z, M_x, M_y), each checked against the published equations evaluated one by
    one in plain Python (`hand_computed`), at an off-nominal load and pressure."""
    kappa, alpha, gamma, Fz, p = point
    P = params_of(SAMPLE, **SCALED)
    c = {k: float(getattr(P, k)) for k in FIELD_NAMES}
    want = hand_computed(c, kappa, alpha, gamma, Fz, p)
    out = mf_evaluate(P, kappa, alpha, Fz, gamma, p, limits=False)
    for name, value in want.items():
        np.testing.assert_allclose(float(getattr(out, name)), value, rtol=1e-10, atol=1e-9,
                                   err_msg=name)


def test_mf52_camber_load_and_moments_match_hand_computed_values():
    """MF 5.2: camber through PHY3 and the camber scalings LGAY, LGAZ; M_z with
    F_y - S_Vyk; M_y proportional to F_z (the MF-Tyre 5.2 forms)."""
    P = params_of(SAMPLE, FITTYP=52, PHY3=0.04, LGAY=1.3, LGAZ=0.7, QSY2=0.01, RVY5=1.9,
                  RVY6=2.0)
    kappa, alpha, gamma, Fz = 0.05, -0.06, 0.03, 3000.0
    c = {k: float(getattr(P, k)) for k in FIELD_NAMES}
    fz0p, dfz = c["FNOMIN"], (Fz - c["FNOMIN"]) / c["FNOMIN"]
    gy, gz = math.sin(gamma) * c["LGAY"], math.sin(gamma) * c["LGAZ"]
    Kya = c["PKY1"] * fz0p * (1 - c["PKY3"] * abs(gy)) * math.sin(2 * math.atan(
        Fz / (c["PKY2"] * fz0p)))
    SHy = c["PHY1"] + c["PHY2"] * dfz + c["PHY3"] * gy
    SVy = Fz * (c["PVY1"] + c["PVY2"] * dfz + (c["PVY3"] + c["PVY4"] * dfz) * gy)
    ay = math.tan(alpha) + SHy
    muy = (c["PDY1"] + c["PDY2"] * dfz) * (1 - c["PDY3"] * gy**2)
    Ey = (c["PEY1"] + c["PEY2"] * dfz) * (1 - (c["PEY3"] + c["PEY4"] * gy) * math.copysign(1, ay))
    By = Kya / (c["PCY1"] * muy * Fz)
    x = By * ay
    Fy0 = muy * Fz * math.sin(c["PCY1"] * math.atan(x - Ey * (x - math.atan(x)))) + SVy
    out = mf_evaluate(P, kappa, alpha, Fz, gamma, limits=False)
    np.testing.assert_allclose(float(out.Fy0), Fy0, rtol=1e-12)
    # M_z = -t (F_y - S_Vyk) + M_zr + s F_x, with gamma_z in the trail
    sht = c["QHZ1"] + c["QHZ2"] * dfz + (c["QHZ3"] + c["QHZ4"] * dfz) * gz
    assert float(out.Mz) != pytest.approx(float(mf_evaluate(
        params_of(SAMPLE, FITTYP=61, PHY3=0.04, QSY2=0.01, RVY5=1.9,
                  RVY6=2.0), kappa, alpha, Fz, gamma, limits=False).Mz), rel=1e-6)
    at = math.tan(alpha) + sht
    kx = (c["PKX1"] + c["PKX2"] * dfz) * math.exp(c["PKX3"] * dfz) * Fz
    at_eq = math.sqrt(at**2 + (kx / Kya) ** 2 * kappa**2)
    Dt = Fz * (c["QDZ1"] + c["QDZ2"] * dfz) * (1 + c["QDZ3"] * gz + c["QDZ4"] * gz**2) \
        * c["UNLOADED_RADIUS"] / fz0p
    Bt = (c["QBZ1"] + c["QBZ2"] * dfz + c["QBZ3"] * dfz**2) * (1 + c["QBZ4"] * gz
                                                               + c["QBZ5"] * abs(gz))
    Et = (c["QEZ1"] + c["QEZ2"] * dfz + c["QEZ3"] * dfz**2) * (
        1 + (c["QEZ4"] + c["QEZ5"] * gz) * (2 / math.pi) * math.atan(Bt * c["QCZ1"] * at))
    x = Bt * at_eq
    t = Dt * math.cos(c["QCZ1"] * math.atan(x - Et * (x - math.atan(x)))) * math.cos(alpha)
    np.testing.assert_allclose(float(out.t), t, rtol=1e-12)
    s = c["UNLOADED_RADIUS"] * (c["SSZ1"] + c["SSZ2"] * float(out.Fy) / fz0p
                                + (c["SSZ3"] + c["SSZ4"] * dfz) * math.sin(gamma))
    mz = -t * (float(out.Fy) - float(out.SVyk)) + float(out.Mzr) + s * float(out.Fx)
    np.testing.assert_allclose(float(out.Mz), mz, rtol=1e-12)
    my = -c["UNLOADED_RADIUS"] * Fz * (c["QSY1"] + c["QSY2"] * float(out.Fx) / c["FNOMIN"]
                                       + c["QSY3"] + c["QSY4"])
    np.testing.assert_allclose(float(out.My), my, rtol=1e-12)


def test_camber_scalings_belong_to_mf52_alone():
    """``LGAX``, ``LGAY``, ``LGAZ`` scale camber in MF 5.2 (PAC2002) only: a 6.1 file that
    carries them (one converted from PAC2002) is read with a warning naming them, and
    gives the same forces and moments as without them; a 5.2 file's camber response does
    change with them, with no warning."""
    scalings = dict(LGAX=0.3, LGAY=0.0, LGAZ=2.0)
    point = (-0.08, 0.05, 3800.0, 0.07)  # kappa, alpha, Fz, gamma [rad]

    def outputs(P):
        out = mf_evaluate(P, *point, limits=False)
        return np.array([float(out.Fx), float(out.Fy), float(out.Mz), float(out.Mz0)])

    with pytest.warns(UserWarning, match=r"LGAX = 0.3, LGAY = 0, LGAZ = 2: MF 5.2 camber"):
        mf61_scaled = params_of(SAMPLE, **scalings)
    np.testing.assert_array_equal(outputs(mf61_scaled), outputs(params_of(SAMPLE)))
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        mf52, mf52_scaled = (outputs(params_of(SAMPLE, FITTYP=52, PHY3=0.04, **extra))
                             for extra in ({}, scalings))
    # F_y, M_z, M_z0 (the sample's F_x hardly depends on camber: its PDX3 is 0)
    assert np.all(np.abs(mf52_scaled - mf52)[1:] > 1e-2 * np.abs(mf52)[1:])


# --- symmetry and limits ----------------------------------------------------------------------

def test_fy_and_mz_are_odd_in_slip_angle_without_camber_and_shifts():
    P = params_of(SAMPLE, PHY1=0.0, PHY2=0.0, PVY1=0.0, PVY2=0.0, PEY3=0.0, PEY4=0.0,
                  QHZ1=0.0, QHZ2=0.0, QEZ4=0.0, QDZ6=0.0, QDZ7=0.0, RHY1=0.0, RHY2=0.0,
                  RVY1=0.0,
                  RVY2=0.0, RHX1=0.0)
    alpha = jnp.linspace(0.01, 0.4, 9)
    for Fz in (1500.0, FZ0, 6000.0):
        pos, neg = mf_evaluate(P, 0.0, alpha, Fz), mf_evaluate(P, 0.0, -alpha, Fz)
        np.testing.assert_allclose(neg.Fy0, -pos.Fy0, rtol=1e-12, atol=1e-9)
        np.testing.assert_allclose(neg.Fy, -pos.Fy, rtol=1e-12, atol=1e-9)
        np.testing.assert_allclose(neg.Mz0, -pos.Mz0, rtol=1e-12, atol=1e-9)
        assert np.all(np.asarray(pos.Fy0) < 0)  # PKY1 < 0: force opposes the slip
    # with the file's shifts it is not odd (so the test above could fail)
    Q = params_of(SAMPLE)
    assert abs(float(mf_evaluate(Q, 0.0, 0.05, FZ0).Fy0 + mf_evaluate(Q, 0.0, -0.05, FZ0).Fy0)) > 1


def test_fx_at_zero_slip_is_the_vertical_shift():
    P = params_of(SAMPLE, PHX1=0.0, PHX2=0.0, PVX1=0.02, PVX2=-0.01, LVX=1.3, LMUX=0.9)
    for Fz in (1000.0, FZ0, 7000.0):
        dfz = (Fz - FZ0) / FZ0
        svx = Fz * (0.02 - 0.01 * dfz) * 1.3 * 0.9
        out = mf_evaluate(P, 0.0, 0.0, Fz)
        np.testing.assert_allclose([out.Fx0, out.Fx], [svx, svx], rtol=1e-12)


def test_combined_slip_forces_lie_inside_the_pure_slip_ones():
    P = params_of(SAMPLE)
    kappa, alpha = jnp.meshgrid(jnp.linspace(-0.5, 0.5, 21), jnp.linspace(-0.3, 0.3, 21))
    for Fz in (1500.0, FZ0, 6000.0):
        out = mf_evaluate(P, kappa, alpha, Fz)
        assert np.all(np.abs(out.Fx) <= np.abs(out.Fx0) + 1e-9)
        assert np.all(np.abs(out.Fy - out.SVyk) <= np.abs(out.Fy0) + 1e-9)
        assert np.all((out.Gxa > 0) & (out.Gxa <= 1 + 1e-12))
        assert np.all((out.Gyk > 0) & (out.Gyk <= 1 + 1e-12))


def test_the_files_ranges_are_applied_as_limits():
    P = params_of(SAMPLE)
    clipped = mf_evaluate(P, 3.0, 2.0, 20000.0, 0.9, 5e5)
    at_edge = mf_evaluate(P, float(P.KPUMAX), float(P.ALPMAX), float(P.FZMAX),
                          float(P.CAMMAX), float(P.PRESMAX))
    for name in ("Fx", "Fy", "Mz", "Mx", "My"):
        np.testing.assert_allclose(getattr(clipped, name), getattr(at_edge, name), rtol=1e-12)
    free = mf_evaluate(P, 3.0, 0.0, 20000.0, limits=False)
    assert float(free.Fx0) != pytest.approx(float(mf_evaluate(P, 3.0, 0.0, 20000.0).Fx0))


def test_low_speed_takes_every_force_and_moment_to_zero_at_standstill():
    P = params_of(SAMPLE)
    rest = mf_evaluate(P, 0.2, 0.1, FZ0, 0.02, vx=0.0)
    for name in ("Fx", "Fy", "Mz", "Mx", "My"):
        if name != "Mx":  # M_x keeps the static camber and QSX1 terms of a standing tire
            assert float(getattr(rest, name)) == 0.0, name
    fast, plain = mf_evaluate(P, 0.2, 0.1, FZ0, 0.02, vx=30.0), mf_evaluate(P, 0.2, 0.1, FZ0,
                                                                            0.02)
    for name in ("Fx", "Fy", "Mz"):
        np.testing.assert_allclose(getattr(fast, name), getattr(plain, name), rtol=1e-12)


def test_summary_values_at_the_nominal_load():
    s = mf_summary(params_of(SAMPLE))
    assert s["version"] == 6.1 and s["Fz"] == FZ0
    assert s["mu_x_drive"] == pytest.approx(1.09, abs=2e-3)  # = PDX1: sin reaches 1
    assert 0.1 < s["kappa_at_mu_x_drive"] < 0.2
    assert s["Kya"] == pytest.approx(s["stated_Kya"], rel=1e-12) and s["Kya"] < 0


# --- differentiability, batching, compilation -------------------------------------------------

def _combined(P, x):
    kappa, alpha, gamma, Fz, p = x
    return mf_forces(P, kappa, alpha, Fz, gamma, p) @ jnp.array([1.0, 0.7, 3.0])


POINTS = {"generic": [0.05, -0.04, 0.02, 4200.0, 2.0e5],
          "zero slip": [0.0, 0.0, 0.0, 3800.0, 1.9e5],
          "zero slip, off-nominal": [0.0, 0.0, 0.01, 2500.0, 2.2e5]}


@pytest.mark.parametrize("where", list(POINTS))
def test_input_gradients_match_finite_differences_forward_and_reverse(where):
    P = params_of(SAMPLE, **SCALED)
    x0 = jnp.asarray(POINTS[where])
    f = jax.jit(lambda x: _combined(P, x))
    fd = fd_grad(f, x0, eps=1e-7)
    rev = np.asarray(jax.jit(jax.grad(f))(x0))
    fwd = np.asarray(jax.jit(jax.jacfwd(f))(x0))
    assert np.all(np.isfinite(rev)) and np.all(np.isfinite(fwd))
    np.testing.assert_allclose(rev, fd, rtol=1e-5, atol=1e-6)
    np.testing.assert_allclose(fwd, rev, rtol=1e-10, atol=1e-10)


def test_gradients_are_finite_where_the_equivalent_trail_slip_vanishes():
    """At kappa = 0 and tan(alpha) = -S_Ht the trail's equivalent slip sqrt(alpha_t^2 +
    (K_x/K_y)^2 kappa^2) (4.E77) is exactly 0: the square root needs its double where."""
    P = params_of(SAMPLE, **SCALED)
    Fz, p = 4200.0, 2.0e5
    dfz = (Fz - float(P.LFZO * P.FNOMIN)) / float(P.LFZO * P.FNOMIN)
    alpha = -math.atan(float(P.QHZ1) + float(P.QHZ2) * dfz)  # alpha_t = 0 at zero camber
    x0 = jnp.asarray([0.0, alpha, 0.0, Fz, p])
    f = jax.jit(lambda x: _combined(P, x))
    rev = np.asarray(jax.jit(jax.grad(f))(x0))
    assert np.all(np.isfinite(rev))
    np.testing.assert_allclose(rev, fd_grad(f, x0, eps=1e-7), rtol=1e-5, atol=1e-6)


@pytest.mark.parametrize("where", ["generic", "zero slip"])
def test_coefficient_gradients_match_finite_differences(where):
    """d(F_x + 0.7 F_y + 3 M_z + M_x + M_y) / d(every finite coefficient), reverse mode,
    against central differences; forward mode against reverse."""
    P = params_of(SAMPLE, **SCALED)
    kappa, alpha, gamma, Fz, p = POINTS[where]
    names = [n for n in FIELD_NAMES if np.isfinite(float(getattr(P, n)))]

    def f(values):
        Q = eqx.tree_at(lambda m: [getattr(m, n) for n in names], P,
                        [values[i] for i in range(len(names))])
        out = mf_evaluate(Q, kappa, alpha, Fz, gamma, p)
        return out.Fx + 0.7 * out.Fy + 3.0 * out.Mz + out.Mx + out.My

    x0 = jnp.asarray([float(getattr(P, n)) for n in names])
    g = np.asarray(jax.jit(jax.grad(f))(x0))
    fd = fd_grad(jax.jit(f), x0, eps=1e-7)
    assert np.all(np.isfinite(g))
    bad = [(n, g[i], fd[i]) for i, n in enumerate(names)
           if not np.isclose(g[i], fd[i], rtol=1e-4, atol=1e-5 * max(1.0, abs(fd[i])))]
    assert not bad, bad
    direction = jnp.asarray(np.random.default_rng(0).normal(size=len(names)))
    _, jvp = jax.jvp(f, (x0,), (direction,))
    np.testing.assert_allclose(float(jvp), float(g @ np.asarray(direction)), rtol=1e-9)
    assert sum(abs(v) > 0 for v in g) > 80  # the coefficients do enter


@pytest.mark.parametrize("tire_cls", [MFTire, RelaxedMFTire])
@pytest.mark.parametrize("state_kind", ["rest", "spinning at rest", "rolling"])
def test_tire_gradients_are_finite_and_match_fd_at_zero_speed(tire_cls, state_kind):
    P = params_of(SAMPLE)
    tire = tire_cls(P, camber=0.01)
    state = tire.init_state() if tire_cls is MFTire else jnp.array([0.05, -0.02])
    x0 = {"rest": [0.0, 0.0, 0.0, 0.3, 3000.0],
          "spinning at rest": [0.0, 0.3, 4.0, 0.3, 3000.0],
          "rolling": [12.0, -0.5, 41.0, 0.3, 3000.0]}[state_kind]

    def f(x):
        vx, vy, omega, r, Fz = x
        forces = tire.forces(state, vx, vy, omega, r, Fz) @ jnp.array([1.0, 0.6, 2.0])
        rates = tire.dynamics(state, vx, vy, omega, r, Fz)
        return forces + jnp.sum(rates) * (0.0 if tire_cls is MFTire else 1.0)

    x0 = jnp.asarray(x0)
    g = np.asarray(jax.jit(jax.grad(f))(x0))
    assert np.all(np.isfinite(g))
    np.testing.assert_allclose(g, fd_grad(jax.jit(f), x0, eps=1e-7), rtol=1e-5, atol=1e-6)
    np.testing.assert_allclose(np.asarray(jax.jacfwd(f)(x0)), g, rtol=1e-10, atol=1e-10)


def test_batched_over_tires_and_operating_points_with_vmap():
    a = params_of(SAMPLE)
    b = params_of(SAMPLE, FITTYP=52, PHY3=0.03, PDX1=1.2, LMUY=0.8)
    both = jax.tree_util.tree_map(lambda x, y: jnp.stack([x, y]), a, b)
    kappa = jnp.linspace(-0.2, 0.2, 5)
    alpha = jnp.linspace(-0.1, 0.15, 5)
    batched = jax.vmap(lambda P: jax.vmap(lambda k, al: mf_forces(P, k, al, 3000.0, 0.02))(
        kappa, alpha))(both)
    for i, P in enumerate((a, b)):
        for j in range(5):
            np.testing.assert_allclose(batched[i, j], mf_forces(P, kappa[j], alpha[j], 3000.0,
                                                                0.02), rtol=1e-12)
    assert not np.allclose(batched[0], batched[1])


def test_a_new_coefficient_value_never_recompiles():
    @eqx.filter_jit
    @eqx.debug.assert_max_traces(max_traces=1)
    def run(P, k):
        return mf_forces(P, k, 0.05, 3000.0)

    P = params_of(SAMPLE)
    run(P, jnp.asarray(0.1))
    new = tuple(jnp.asarray(v, dtype=float) for v in (1.3, 0.8, 5.2))
    run(eqx.tree_at(lambda m: (m.PDX1, m.LMUY, m.version), P, new), jnp.asarray(0.2))
    run(params_of(SAMPLE, PKY1=-20.0, FITTYP=62), jnp.asarray(0.0))


# --- transient response and the vehicles ------------------------------------------------------

def test_relaxed_slips_lag_with_the_files_relaxation_lengths():
    """At constant speed and slip the relaxed slips follow a first-order lag with time
    constant sigma / V, and the forces tend to those of the static tire."""
    P = params_of(SAMPLE)
    tire, static = RelaxedMFTire(P), MFTire(P)
    V, r, Fz = 20.0, 0.3, FZ0
    omega, vy = V * 1.05 / r, -0.04 * V  # kappa = 0.05, tan(alpha) = -0.04
    sk, sa = (float(x) for x in mf_relaxation_lengths(P, Fz))
    assert 0.3 < sk < 1.5 and 0.3 < sa < 1.5  # PTX1 R0 and PTY1 sin(2 atan(1/PTY2)) R0
    np.testing.assert_allclose(sk, 1.9021 * 0.376, rtol=1e-9)  # PTX1 R0 at nominal load
    step = jax.jit(lambda s, h: s + h * tire.dynamics(s, V, vy, omega, r, Fz))
    state, h = tire.init_state(), 1e-5
    t_k = sk / V
    for _ in range(int(round(t_k / h))):
        state = step(state, h)
    np.testing.assert_allclose(float(state[0]), 0.05 * (1 - math.exp(-1)), rtol=2e-3)
    np.testing.assert_allclose(float(state[1]), -0.04 * (1 - math.exp(-sk / sa)), rtol=2e-3)
    settled = jnp.array([0.05, -0.04])
    np.testing.assert_allclose(tire.forces(settled, V, vy, omega, r, Fz),
                               static.forces(static.init_state(), V, vy, omega, r, Fz),
                               rtol=1e-12)


@pytest.mark.parametrize("tire_cls", [MFTire, RelaxedMFTire])
def test_a_tir_tire_drives_the_half_car(tire_cls):
    """A step steer of the rally car on the sample tire: the car turns left for a left
    steer, the lateral forces point left, and it stays on a bounded, finite path."""
    from vehsim.vehicle.maneuvers import step_steer

    P = params_of(SAMPLE)
    car = HalfCar(rally_gravel(), tire_cls(P))
    ts = jnp.linspace(0.0, 2.0, 21)
    tr = simulate(car, ts, step_steer(0.05, t_step=0.2), car.init_state(vx=15.0),
                  rtol=1e-7, atol=1e-7)
    assert bool(tr.ok)
    assert np.all(np.isfinite(np.asarray(tr.states)))
    assert float(tr["yaw_rate"][-1]) > 0.05 and float(tr["ay"][-1]) > 1.0
    assert float(tr["Fy_F"][-1]) > 0


def test_a_tir_tire_brakes_the_quarter_car():
    P = params_of(SAMPLE)
    qc = QuarterCar(MFLongitudinalTire(P, Fz=3500.0), mass=350.0, inertia=1.0, radius=0.3,
                    Fn_static=3500.0)
    sol = simulate_quarter_car(qc, jnp.linspace(0.0, 1.0, 11), 400.0, 20.0,
                               solver=diffrax.Tsit5())
    v = np.asarray(sol.v)
    assert np.all(np.isfinite(v)) and np.all(np.diff(v) < 0) and v[-1] < 18.0
    assert np.all(np.asarray(sol.Fx)[1:] < 0)


@pytest.mark.parametrize("Fz", [500.0, 3000.0, 6000.0, 8000.0])
def test_cornering_stiffness_is_4E25_on_both_sides_of_its_rewritten_branch(Fz):
    """K_ya = PKY1 Fz0 sin(PKY4 atan(Fz / (PKY2 Fz0))) (4.E25, no camber, nominal pressure),
    computed per unit load two ways (|Fz| below PKY2 Fz0, 5265 N for the sample file, and
    above it: 6000 and 8000 N, within FZMAX); at PKY2 = 0 (a file without it) the limit PKY1 Fz0 sin(PKY4 pi / 2), with
    finite forces whose derivative in PKY2 is the one-sided slope in both modes."""
    P = params_of(SAMPLE)
    f = {k: float(getattr(P, k)) for k in ("PKY1", "PKY2", "PKY4", "FNOMIN", "LFZO", "LKY")}
    fz0 = f["FNOMIN"] * f["LFZO"]
    hand = f["PKY1"] * fz0 * math.sin(f["PKY4"] * math.atan(Fz / (f["PKY2"] * fz0))) * f["LKY"]
    np.testing.assert_allclose(abs(float(mf_evaluate(P, 0.0, 0.0, Fz).Kya)), abs(hand),
                               rtol=1e-12)
    P0 = eqx.tree_at(lambda p: p.PKY2, P, jnp.asarray(0.0))
    limit = f["PKY1"] * fz0 * math.sin(f["PKY4"] * math.pi / 2) * f["LKY"]
    np.testing.assert_allclose(abs(float(mf_evaluate(P0, 0.0, 0.0, Fz).Kya)), abs(limit),
                               rtol=1e-12)

    def fy(pky2):
        return mf_forces(eqx.tree_at(lambda p: p.PKY2, P, pky2), 0.02, 0.05, Fz)[1]

    rev, fwd = jax.grad(fy)(0.0), jax.jvp(fy, (0.0,), (1.0,))[1]
    h = 1e-6
    slope = (-3 * fy(0.0) + 4 * fy(h) - fy(2 * h)) / (2 * h)  # one-sided, second order
    assert np.isfinite(float(fy(0.0))) and float(rev) == pytest.approx(float(fwd), rel=1e-12)
    np.testing.assert_allclose(float(rev), float(slope), rtol=1e-5)


def test_a_slip_angle_past_the_tangents_pole_keeps_the_forces_sign():
    """Files state ALPMAX = 1.5708, just past pi/2, where tan(alpha) changes sign: the limits
    keep |alpha| below the pole, so Fy at 2 rad (and at 1.5708) is Fy just below pi/2."""
    P = params_of(SAMPLE)
    assert float(P.ALPMAX) > math.pi / 2
    below = float(mf_forces(P, 0.0, math.pi / 2 - 1e-6, FZ0)[1])
    for alpha in (1.5708, 2.0):
        got = float(mf_forces(P, 0.0, alpha, FZ0)[1])
        assert np.sign(got) == np.sign(below) and got == pytest.approx(below, rel=1e-3)
