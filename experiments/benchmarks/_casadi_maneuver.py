"""The maneuver problem of ocp_vs_ipopt in CasADi, solved by IPOPT: the reduced half-car,
the corridor with the same smooth inner corners, the bounds and the boundary conditions.

This module imports neither JAX nor vehsim, so that a process timing CasADi + IPOPT from
start to finish (``ocp_vs_ipopt.py --end-to-end``) pays only for what a CasADi user's script
would: the road (`road_data`) and the bounds (`LIMIT_NAMES`) arrive as plain data.
"""

from __future__ import annotations

import time
from types import SimpleNamespace

import casadi as ca
import numpy as np


LIMIT_NAMES = ("SMOOTHING", "SPEED_FLOOR", "KAPPA_MIN", "KAPPA_MAX", "DELTA_MAX", "TF_MIN")
"""The bounds of the maneuver problem (vehsim.optimal.roads/shooting), in ``limits``."""


def road_data(rd) -> dict:
    """A road (vehsim's `Road`, or anything with the same attributes) as plain JSON data."""
    ends = {k: dict(fixed=[list(f) for f in b.fixed], box=[[n, list(lh)] for n, lh in b.box],
                    zero_velocity=b.zero_velocity)
            for k, b in (("start", rd.start), ("end", rd.end))}
    return dict(outer=list(rd.outer), corners=[[list(p) for p in c] for c in rd.corners], **ends)


def _road(data: dict):
    end = {k: SimpleNamespace(fixed=[tuple(f) for f in data[k]["fixed"]],
                              box=[(n, tuple(lh)) for n, lh in data[k]["box"]],
                              zero_velocity=data[k]["zero_velocity"]) for k in ("start", "end")}
    return SimpleNamespace(outer=tuple(data["outer"]), corners=data["corners"], **end)


def _smooth_max(a, b, eps):
    t = (a - b) / eps
    t2 = t * t
    p = ca.if_else(ca.fabs(t) < 1.0, t2 * (15.0 / 8.0 - t2 * (5.0 / 4.0 - t2 * 3.0 / 8.0)),
                   ca.fabs(t))
    return 0.5 * (a + b) + 0.5 * eps * p


def _corridor(rd, x, y, eps):
    xmin, xmax, ymin, ymax = rd.outer
    cons = []
    if xmin is not None:
        cons.append(x - xmin)
    if xmax is not None:
        cons.append(xmax - x)
    if ymin is not None:
        cons.append(y - ymin)
    if ymax is not None:
        cons.append(ymax - y)
    for planes in rd.corners:
        vals = [nx * x + ny * y - b for nx, ny, b in planes]
        m = vals[0]
        for v in vals[1:]:
            m = _smooth_max(m, v, eps)
        cons.append(m)
    return cons


def axle_velocities(vx, vy, r, d):
    r"""$(V_{Fx}, V_{Fy}, V_{Rx}, V_{Ry})$: the axle centres' velocities in the wheel frames
    (CasADi; the front's rotated by $-\delta$)."""
    lF, lR = 1.3, 1.4
    VFx = vx * ca.cos(d) + (vy + lF * r) * ca.sin(d)
    VFy = -vx * ca.sin(d) + (vy + lF * r) * ca.cos(d)
    return VFx, VFy, vx, vy - lR * r


def body_model(D, vx, vy, r, kF, kR, d, B=7.0):
    r"""The reduced half-car's body accelerations $(\dot v_x, \dot v_y, \dot r)$ and axle
    speeds $(V_{Fx}, V_{Rx})$ at the inputs $(\kappa_F, \kappa_R, \delta)$, in CasADi (the
    formulas of docs/maneuvers.md); the tire's peak ``D`` and its ``B`` (the gravel's 7, or
    a number or symbol scaled with the grip, `vehsim.scaled_planning_car`)."""
    m, Iz, lF, lR, h, g = 1450.0, 2740.0, 1.3, 1.4, 0.4, 9.81
    C = 1.6
    VFx, VFy, VRx, VRy = axle_velocities(vx, vy, r, d)

    def mu(kappa, Vx, Vy):
        sx = -kappa / (1 + kappa)
        sy = (Vy / Vx) / (1 + kappa)
        s = ca.sqrt(sx * sx + sy * sy + 1e-18)
        g_ = D * ca.sin(C * ca.atan(B * s)) / s
        return -sx * g_, -sy * g_

    muFx, muFy = mu(kF, VFx, VFy)
    muRx, muRy = mu(kR, VRx, VRy)
    muFb = muFx * ca.cos(d) - muFy * ca.sin(d)
    FzF = m * g * (lR - h * muRx) / (lF + lR + h * (muFb - muRx))
    FzR = m * g - FzF
    fFx, fFy, fRx, fRy = muFx * FzF, muFy * FzF, muRx * FzR, muRy * FzR
    Fbx = fFx * ca.cos(d) - fFy * ca.sin(d) + fRx
    Fby = fFx * ca.sin(d) + fFy * ca.cos(d) + fRy
    Mz = (fFy * ca.cos(d) + fFx * ca.sin(d)) * lF - fRy * lR
    return ca.vertcat(Fbx / m + r * vy, Fby / m - r * vx, Mz / Iz), ca.vertcat(VFx, VRx)


def casadi_model(D):
    """dX/dtau and the axle speeds of the reduced half-car, in CasADi (the formulas of
    docs/maneuvers.md)."""
    X = ca.SX.sym("X", 10)
    v = ca.SX.sym("v", 3)
    psi, vx, vy, r, kF, kR, d, tf = X[2], X[3], X[4], X[5], X[6], X[7], X[8], X[9]
    body, axle_speeds = body_model(D, vx, vy, r, kF, kR, d)
    rates = ca.vertcat(vx * ca.cos(psi) - vy * ca.sin(psi), vx * ca.sin(psi) + vy * ca.cos(psi),
                       r, body)
    dX = ca.vertcat(tf * rates, v, 0)
    return ca.Function("f", [X, v], [dX]), ca.Function("axles", [X], [axle_speeds])


def _dense_weights(theta):
    """RK4's third-order continuous extension, as vehsim.optimal.shooting's."""
    t2, t3 = theta * theta, theta**3
    mid = t2 - 2.0 * t3 / 3.0
    return (theta - 1.5 * t2 + 2.0 * t3 / 3.0, mid, mid, -0.5 * t2 + 2.0 * t3 / 3.0)


def _clearance(planes, d, eps=1e-3):
    """Corner clearance margin of chord ``d``, as vehsim.optimal.shooting's."""
    normals = [(nx / np.hypot(nx, ny), ny / np.hypot(nx, ny)) for nx, ny, _ in planes]
    m = 0
    for i, ni in enumerate(normals):
        for nj in normals[i + 1:]:
            if ni[0] * nj[0] + ni[1] * nj[1] < -1.0 + 1e-9:
                continue
            a, b = (ca.sqrt((d[0] * n[0] + d[1] * n[1]) ** 2 + eps**2) for n in (ni, nj))
            m = ca.fmax(m, a * b / (a + b))
    return m


def ipopt_solve(road: dict, limits: dict, objective, D, N, xs0, us0, method="rk4", tf_max=4.0,
                rate_weight=1e-5, warm=None, corner_clearance=True, interior_points=0):
    """Build the problem on ``road`` (`road_data`) with ``limits`` (`LIMIT_NAMES`) and solve it
    from (``xs0``, ``us0``); the solver call is timed (``wall``). ``corner_clearance`` and
    ``interior_points`` as vehsim's `ManeuverOCP` (rk4 only): the inner corners at both ends
    of every chord between consecutive constrained points hold with its clearance margin,
    and the corridor also holds at ``interior_points`` points of RK4's continuous
    extension."""
    rd, lim = _road(road), SimpleNamespace(**limits)
    f, axles = casadi_model(D)
    opti = ca.Opti()
    X = opti.variable(10, N + 1)
    V = opti.variable(3, N)
    h = 1.0 / N
    n_corners = len(rd.corners)
    thetas = [(j + 1) / (interior_points + 1) for j in range(interior_points)]
    for k in range(N):
        xk, vk = X[:, k], V[:, k]
        if method == "rk4":
            k1 = f(xk, vk)
            k2 = f(xk + 0.5 * h * k1, vk)
            k3 = f(xk + 0.5 * h * k2, vk)
            k4 = f(xk + h * k3, vk)
            opti.subject_to(X[:, k + 1] == xk + h / 6 * (k1 + 2 * k2 + 2 * k3 + k4))
            pts = [xk[:2]]
            for t in thetas:
                b = _dense_weights(t)
                xd = xk + h * (b[0] * k1 + b[1] * k2 + b[2] * k3 + b[3] * k4)
                pts.append(xd[:2])
                for c in _corridor(rd, xd[0], xd[1], lim.SMOOTHING):
                    opti.subject_to(c >= 0)
            pts.append(X[:2, k + 1])
            if corner_clearance and n_corners:
                for p, q in zip(pts[:-1], pts[1:]):
                    for e in (p, q):
                        cs = _corridor(rd, e[0], e[1], lim.SMOOTHING)[-n_corners:]
                        for c, planes in zip(cs, rd.corners):
                            opti.subject_to(c - _clearance(planes, q - p) >= 0)
        else:
            opti.subject_to(X[:, k + 1] == xk + h / 2 * (f(xk, vk) + f(X[:, k + 1], vk)))
    for k in range(N + 1):
        xk = X[:, k]
        for c in _corridor(rd, xk[0], xk[1], lim.SMOOTHING):
            opti.subject_to(c >= 0)
        opti.subject_to(axles(xk) >= lim.SPEED_FLOOR)
        opti.subject_to(opti.bounded(lim.KAPPA_MIN, xk[6], lim.KAPPA_MAX))
        opti.subject_to(opti.bounded(lim.KAPPA_MIN, xk[7], lim.KAPPA_MAX))
        opti.subject_to(opti.bounded(-lim.DELTA_MAX, xk[8], lim.DELTA_MAX))
        opti.subject_to(xk[9] >= lim.TF_MIN)
    names = {"x": 0, "y": 1, "psi": 2, "yaw_rate": 5}
    for bset, xk in ((rd.start, X[:, 0]), (rd.end, X[:, N])):
        for n, val in bset.fixed:
            opti.subject_to(xk[names[n]] == val)
        for n, (lo, hi) in bset.box:
            opti.subject_to(opti.bounded(lo, xk[names[n]], hi))
        psi, vx, vy = xk[2], xk[3], xk[4]
        lat = (vx * ca.sin(psi) + vy * ca.cos(psi) if bset.zero_velocity == "y"
               else vx * ca.cos(psi) - vy * ca.sin(psi))
        opti.subject_to(lat == 0)
    reg = rate_weight * ca.sumsqr(V) / N
    if objective == "min-time":
        opti.minimize(X[9, N] + reg)
    else:
        opti.subject_to(X[9, N] <= tf_max)
        opti.minimize(-ca.sqrt(X[3, N] ** 2 + X[4, N] ** 2) + reg)
    return solve_opti(opti, X, V, xs0, us0)


def solve_opti(opti, X, V, xs0, us0, **ipopt_options) -> dict:
    """IPOPT (MUMPS, tolerance 1e-8, quiet; ``ipopt_options`` added) on the problem of
    ``opti`` from the knots ``xs0`` and controls ``us0`` of its variables ``X`` and ``V``.

    The NLP is expanded to CasADi's scalar graph (``expand``: its functions and their
    derivatives evaluated as SX, several times faster than the MX graph of function calls
    that `Opti` builds) and the solver is built (`Opti.to_function`: the nlpsol, its
    Jacobian and Hessian functions) before the clock starts: only the solver call is timed
    (``wall``). Returns the solution, status and iterations."""
    opti.solver("ipopt", {"print_time": False, "expand": True},
                {"print_level": 0, "tol": 1e-8, "max_iter": 3000, "linear_solver": "mumps",
                 "sb": "yes", **ipopt_options})
    solver = opti.to_function("ipopt_solve", [X, V], [X, V])
    t0 = time.perf_counter()
    xs, us = solver(np.asarray(xs0).T, np.asarray(us0).T)
    wall = time.perf_counter() - t0
    nu, M = V.shape
    stats = solver.stats()
    return dict(ok=bool(stats.get("success", False)), wall=wall, xs=np.asarray(xs).T,
                us=np.asarray(us).reshape(nu, M).T,
                iterations=int(stats.get("iter_count", -1)),
                status=str(stats.get("return_status")))
