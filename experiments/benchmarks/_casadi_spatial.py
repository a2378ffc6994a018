"""The long-road problem of ocp_vs_ipopt (``--stages``) in CasADi, solved by IPOPT: the
reduced half-car in the road's curvilinear frame with arc length as the independent
variable, the transcription of `vehsim.optimal.curvilinear` (one RK4 step per stage, the
corridor on the lateral offset at the nodes and at each stage's midpoint on the cubic
Hermite interpolant, the gates, periodic conditions for a lap).

Like `_casadi_maneuver`, this module imports neither JAX nor vehsim: the road arrives as
plain data (`road_arrays` in ocp_vs_ipopt.py), the bounds as ``limits``.
"""

from __future__ import annotations

import casadi as ca
import numpy as np
from _casadi_maneuver import body_model, solve_opti


NX = 9
NU = 3


def spatial_model(D):
    r"""$dX/ds$ of $X = (n, \xi, v_x, v_y, r, \kappa_F, \kappa_R, \delta, t)$ under the input
    rates $v$ at the road curvature $k$, and the axle speeds:
    $\dot s = (v_x\cos\xi - v_y\sin\xi)/(1 - nk)$, $\dot n = v_x\sin\xi + v_y\cos\xi$,
    $\dot\xi = r - k\dot s$, every rate divided by $\dot s$, $dt/ds = 1/\dot s$."""
    X = ca.SX.sym("X", NX)
    v = ca.SX.sym("v", NU)
    k = ca.SX.sym("k")
    n, xi, vx, vy, r, kF, kR, d = (X[i] for i in range(8))
    body, axle_speeds = body_model(D, vx, vy, r, kF, kR, d)
    sdot = (vx * ca.cos(xi) - vy * ca.sin(xi)) / (1 - n * k)
    ndot = vx * ca.sin(xi) + vy * ca.cos(xi)
    dX = ca.vertcat(ndot, r - k * sdot, body, v * sdot, 1.0) / sdot
    return (ca.Function("f", [X, v, k], [dX]), ca.Function("axles", [X], [axle_speeds]))


def ipopt_solve(road: dict, limits: dict, objective: str, D: float, xs0, us0,
                rate_weight=1e-4, tf_max=60.0, mu_init=0.1):
    """Build the problem on ``road`` (plain arrays, as `road_arrays` in ocp_vs_ipopt.py
    gives them: ``length``, ``closed``, ``curvature`` (M, 3) at each stage's RK4 points,
    ``corridor`` (M+1, 2) and ``corridor_mid`` (M, 2) lower/upper bounds on n, the gates'
    ``start_lateral``/``end_lateral``, ``start_speed``/``end_speed`` (None: free) and
    ``stage_lengths`` (M,) (optional: else uniform, ``length`` / M)) and
    solve it from (``xs0``, ``us0``) (knots (M+1, 9), input rates (M, 3)) with IPOPT's
    initial barrier ``mu_init``; the solver call is timed (``wall``)."""
    curv = np.asarray(road["curvature"], float)
    M = curv.shape[0]
    L = float(road["length"])
    hs = np.asarray(road.get("stage_lengths", np.full(M, L / M)), float)
    lim = limits
    f, axles = spatial_model(D)
    opti = ca.Opti()
    X = opti.variable(NX, M + 1)
    V = opti.variable(NU, M)
    node = np.asarray(road["corridor"], float)
    mid = np.asarray(road["corridor_mid"], float)

    def slope(x, k):  # dn/ds
        return f(x, ca.DM.zeros(NU), k)[0]

    for j in range(M):
        xk, vk = X[:, j], V[:, j]
        k0, k1, k2 = curv[j]
        h = float(hs[j])
        f1 = f(xk, vk, k0)
        f2 = f(xk + 0.5 * h * f1, vk, k1)
        f3 = f(xk + 0.5 * h * f2, vk, k1)
        f4 = f(xk + h * f3, vk, k2)
        opti.subject_to(X[:, j + 1] == xk + h / 6 * (f1 + 2 * f2 + 2 * f3 + f4))
        # the lateral offset at the stage's midpoint on the cubic Hermite interpolant
        n_mid = 0.5 * (xk[0] + X[0, j + 1]) + h / 8 * (slope(xk, k0) - slope(X[:, j + 1], k2))
        opti.subject_to(opti.bounded(mid[j, 0], n_mid, mid[j, 1]))
    for j in range(M + 1):
        xk = X[:, j]
        opti.subject_to(opti.bounded(node[j, 0], xk[0], node[j, 1]))
        opti.subject_to(axles(xk) >= lim["SPEED_FLOOR"])
        opti.subject_to(opti.bounded(lim["KAPPA_MIN"], xk[5], lim["KAPPA_MAX"]))
        opti.subject_to(opti.bounded(lim["KAPPA_MIN"], xk[6], lim["KAPPA_MAX"]))
        opti.subject_to(opti.bounded(-lim["DELTA_MAX"], xk[7], lim["DELTA_MAX"]))
    opti.subject_to(X[8, 0] == 0)
    if road["closed"]:
        opti.subject_to(X[:8, M] == X[:8, 0])
    else:
        for end, xk in (("start", X[:, 0]), ("end", X[:, M])):
            opti.subject_to(xk[1] == 0)
            opti.subject_to(xk[4] == 0)
            opti.subject_to(xk[2] * ca.sin(xk[1]) + xk[3] * ca.cos(xk[1]) == 0)
            lo, hi = road[f"{end}_lateral"]
            opti.subject_to(opti.bounded(lo, xk[0], hi))
            if road[f"{end}_speed"] is not None:
                opti.subject_to(xk[2] == road[f"{end}_speed"])
    reg = rate_weight * sum(float(hs[j]) * ca.sumsqr(V[:, j]) for j in range(M))
    if objective == "min-time":
        opti.minimize(X[8, M] + reg)
    else:
        opti.subject_to(X[8, M] <= tf_max)
        opti.minimize(-ca.sqrt(X[2, M] ** 2 + X[3, M] ** 2) + reg)
    return solve_opti(opti, X, V, xs0, us0, mu_init=mu_init)
