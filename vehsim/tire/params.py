"""Published tire parameter sets (sources in docs/parameters.md).

Each set is a function returning fresh parameter modules; `vehsim.preset(name)` looks them
up by name among every preset (`vehsim.params`). Values we could not confirm from a second
source are kept, and marked "unverified".
"""

from __future__ import annotations

from .load import PolynomialLoad
from .lugre import LuGreParams
from .lugre2d import LuGre2DParams
from .lugre2d_fit import bernstein_load
from .magic_formula import MagicFormula1987Params


def table3() -> LuGreParams:
    """Longitudinal LuGre, report Table 3 (the data of Fig. 7), distributed model.

    sigma0 = 181.54 1/m, sigma2 = 0.0018 s/m, mu_c = 0.8, mu_s = 1.55, v_s = 6.57 m/s,
    L = 0.2 m, alpha = 1/2 (report footnote 1). sigma1 = 0.7 s/m is not in Table 3 (it only
    enters transients); it is the value commonly quoted with this set (**unverified**).
    Source: Tsiotras (2004), Table 3; Canudas de Wit et al., VSD 39(3), 2003.
    """
    return LuGreParams(
        sigma0=181.54, sigma1=0.7, sigma2=0.0018, mu_c=0.8, mu_s=1.55, v_s=6.57,
        alpha=0.5, theta=1.0, L=0.2,
    )


def cdc1999(theta: float = 1.0) -> LuGreParams:
    """Longitudinal LuGre of Canudas de Wit and Tsiotras, CDC 1999.

    sigma0 = 40 1/m, sigma1 = 4.9487 s/m, sigma2 = 0.0018 s/m, mu_c = 0.5, mu_s = 0.9,
    v_s = 12.5 m/s, L = 0.25 m, alpha = 1/2 (their operating point is v = 20 m/s). The road
    condition `theta` scales the bristle decay, so steady friction scales roughly as g/theta
    (1/theta in {1, 0.8, 0.6, 0.4}: dry to slippery).
    Source: Canudas de Wit and Tsiotras, "Dynamic tire friction models for vehicle traction
    control", 38th IEEE CDC, 1999, pp. 3746-3751.
    """
    return LuGreParams(
        sigma0=40.0, sigma1=4.9487, sigma2=0.0018, mu_c=0.5, mu_s=0.9, v_s=12.5,
        alpha=0.5, theta=theta, L=0.25,
    )


def bakker1987() -> MagicFormula1987Params:
    """Magic Formula coefficients of Bakker, Nyborg and Pacejka (1987), SAE 870421.

    In the paper's units (Fz in kN, slip angle in degrees, slip in percent, N and N m);
    `vehsim.tire.magic_formula` converts, so users pass N, rad and slip ratio.
    Lateral (C = 1.30): a1..a8 = -22.1, 1011, 1078, 1.82, 0.208, 0, -0.354, 0.707;
    camber a9..a13 = 0.028, 0, 14.8, 0.022, 0. Longitudinal (C = 1.65): b1..b8 = -21.3, 1144,
    49.6, 226, 0.069, -0.006, 0.056, 0.486 (copies with b5 = 0.69 carry a typo). Aligning
    moment (C = 2.40): c1..c8 = -2.72, -2.28, -1.86, -2.73, 0.110, -0.070, 0.643, -4.04;
    camber c9..c13 = 0.015, -0.066, 0.945, 0.030, 0.070 (camber not modelled).
    Source: Bakker, Nyborg and Pacejka, SAE 870421 (1987), as listed in docs/parameters.md;
    these are the Magic Formula values of the report's Fig. 15 (its ref. [5]).
    """
    return MagicFormula1987Params(
        a=[-22.1, 1011.0, 1078.0, 1.82, 0.208, 0.0, -0.354, 0.707, 0.028, 0.0, 14.8, 0.022, 0.0],
        b=[-21.3, 1144.0, 49.6, 226.0, 0.069, -0.006, 0.056, 0.486],
        c=[-2.72, -2.28, -1.86, -2.73, 0.110, -0.070, 0.643, -4.04, 0.015, -0.066, 0.945,
           0.030, 0.070],
        C_y=1.30, C_x=1.65, C_z=2.40,
    )


def lugre2d_bakker1987() -> LuGre2DParams:
    """2D LuGre whose steady state matches the `bakker1987` Magic Formula (report Fig. 15).

    Found by the fit `vehsim.tire.lugre2d_fit.fit_to_magic_formula` did before it fitted
    M_z (F_x and F_y at one load, residuals over Fz; optimistix Levenberg-Marquardt,
    converged in 208 steps from sigma0 = (180, 180) 1/m, mu_k = (0.8, 0.7), mu_s = (1.2, 1.0),
    v_s = 6.57 m/s, gamma = 0.5): distributed model with uniform load, L = 0.2 m (Table 3),
    Fz = 4000 N, v = 20 m/s, pure-slip curves F_x(kappa), kappa in [-0.5, 0.5] and
    F_y(alpha), alpha in [0.5, 20] deg. **Fit residual** |F_LuGre - F_MF| / Fz:
    RMS 0.0142, max 0.0290. Held (not fitted; they do not enter the steady state or were set
    to zero): sigma1 = (0.7, 0.7) s/m (Table 3's commonly quoted value, unverified),
    sigma2 = (0, 0) s/m. The report does not list its 2D parameters; this set is ours.
    Its M_z was not fitted (peak 75 N m against the Magic Formula's 52 N m at 4 kN, and no
    sign change): for M_z see `lugre2d_bakker1987_mz`.
    """
    return LuGre2DParams(
        sigma0=[379.0400580476603, 179.61587440368314], sigma1=[0.7, 0.7], sigma2=[0.0, 0.0],
        mu_k=[0.6761008743057866, 0.6503576005342454],
        mu_s=[2.6012541280115338, 2.7684943911269353],
        v_s=1.4096457057112053, gamma=0.4319301951972794, L=0.2,
    )


_MZ_FITS = {  # found by fit_to_magic_formula, see lugre2d_bakker1987_mz
    False: dict(sigma0=[216.2305604565792, 130.26087912413195],
                mu_k=[0.7831018208526981, 0.8470489910822119],
                mu_s=[1.2943769370132454, 1.0436288333081138], v_s=4.975226298954832,
                gamma=1.1259566668025227, L0=0.3828473898975008,
                exponent=-0.11247379537198063, weights=[0.0, 0.10403409462590106, 1.0, 0.0, 0.0]),
    True: dict(sigma0=[268.2695798887864, 261.7133647299259],
               mu_k=[0.4479091101404238, 0.7386650148904215],
               mu_s=[2.6478914312980226, 1.3052380201295688], v_s=1.2180994119957882,
               gamma=0.26008171526128543, L0=0.2723405976974209,
               exponent=-0.16688043999472066, weights=[0.0, 0.0, 1.0, 0.0, 0.0]),
}


def lugre2d_bakker1987_mz(Fz: float = 4000.0, symmetric: bool = False
                          ) -> tuple[LuGre2DParams, PolynomialLoad]:
    """2D LuGre and normal-load shape whose steady F_x, F_y and M_z match the `bakker1987`
    Magic Formula at 2, 4 and 6 kN together (report Fig. 15). Returns `(params, load)` at
    the load `Fz` [N]; `symmetric=True`: the best load symmetric about the patch centre.

    Found by `vehsim.fit_to_magic_formula` (defaults: pure-slip F_x(kappa), kappa in
    [-0.5, 0.5], F_y and M_z(alpha), alpha in [0.5, 20] deg, v = 20 m/s, each curve relative
    to its peak; optimistix Levenberg-Marquardt, rtol = atol = 1e-6) from the
    `lugre2d_bakker1987` values with L = 0.15 m, a uniform load and p = 0: converged in 933
    steps (symmetric: stopped at 1000 steps, its two outer weights creeping to their bound,
    zero, with the errors settled to the digits below). Fitted besides
    the LuGre parameters: the load shape, a quartic in Bernstein form with weights
    (w_0..w_4) = (0, 0.104, 1, 0, 0) (symmetric: (0, 0, 1, 0, 0), q ~ xi^2 (1 - xi)^2):
    zero at both edges, its centre of pressure 0.016 L ahead of the centre (symmetric: 0);
    and the patch length L = L_0 (Fz / 4 kN)^p with L_0 = 0.383 m, p = -0.112 (symmetric:
    0.272 m, -0.167), both outside what a tyre's patch does (about 0.15 m at 4 kN, growing
    with load): the model has no other way to follow the Magic Formula's cornering
    stiffness per unit load, which falls with load, and its trail, which grows
    (docs/parameters.md). **Errors** (RMS in % of each curve's peak, 2 / 4 / 6 kN):
    F_x 5.0 / 1.3 / 5.0, F_y 5.6 / 3.2 / 8.6, M_z 20.6 / 16.2 / 30.2 (symmetric: F_x
    5.1 / 1.2 / 5.0, F_y 8.6 / 8.3 / 13.1, M_z 40.8 / 31.9 / 36.2). Held: sigma1 = (0.7,
    0.7) s/m (unverified, as in `lugre2d_bakker1987`), sigma2 = (0, 0) s/m. This set is
    ours; the report does not list its 2D parameters.
    """
    f = _MZ_FITS[bool(symmetric)]
    L = f["L0"] * (float(Fz) / 4000.0) ** f["exponent"]
    params = LuGre2DParams(sigma0=f["sigma0"], sigma1=[0.7, 0.7], sigma2=[0.0, 0.0],
                           mu_k=f["mu_k"], mu_s=f["mu_s"], v_s=f["v_s"], gamma=f["gamma"], L=L)
    return params, bernstein_load(f["weights"])

