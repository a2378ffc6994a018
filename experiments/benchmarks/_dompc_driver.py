r"""The horizon problem of vehsim's receding-horizon driver as a do-mpc MPC.

The model is do-mpc's *discrete* model with the arc length as the independent variable
(``t_step`` = H/M is a step in s): the reduced half-car in the road's frame (`spatial_rate`,
the formulas of `vehsim.spatial_rhs`, the body rates from `_casadi_maneuver.body_model`),
one classical RK4 step per stage as vehsim's transcription, the state
$X = (n, \xi, v_x, v_y, r, \kappa_F, \kappa_R, \delta, t)$ and the input rates
$u = d(\kappa_F, \kappa_R, \delta)/ds$. Everything that moves with the car's station $s_0$
is a time-varying parameter (tvp) of each stage $k$: the curvature at the stage's RK4 points
(``kap0``, ``kap1``, ``kap2``), the per-stage grip multiplier of the tire's $D$ (``grip``),
the corridor at the node and at the stage's midpoint (``n_lo``, ``n_hi``, ``mid_lo``,
``mid_hi``), the bound on the axles' combined slip (``slip_max``, widened at a sliding start
as vehsim's) and, on the last stage only (``last`` = 1), the corridor at the end node and the
terminal speed bound (``end_lo``, ``end_hi``, ``speed_max``).

Constraints (as `HorizonOCP`): the corridor at every node and at each stage's midpoint on the
cubic Hermite interpolant of $n$ (as `CurvilinearManeuverOCP`), the axle speeds above the
floor, the slips and the steering angle in their boxes, the steering rate
$|u_\delta \dot s| \le$ the actuator's rate, each axle's combined slip
$\sqrt{\kappa_i^2 + (V_{iy}/V_{ix})^2}/(1 + \kappa_i) \le$ ``slip_max`` as vehsim's polynomial
$\kappa_i^2V_{ix}^2 + V_{iy}^2 - \ell^2(1 + \kappa_i)^2V_{ix}^2 \le 0$, and at $s_0 + H$ the
corridor, the axle speeds, the last stage's slip bound or its tire's peak slip where larger
(`end_slip_limit`), the speed $|v| \le$ ``speed_max``
($\beta\sqrt{D}\,v_1(s_0 + H)$), the sideslip $|v_y| \le \sigma v_x$ and the heading
$|\xi| \le \xi_{max}$. Objective
$t(H) + w\sum_k h|u_k|^2$.

The bounds on the slips and the steering angle are do-mpc's state bounds (knots 1..M; the
first knot is fixed), $|\xi(H)| \le \xi_{max}$ a terminal bound; the constraints of the
end knot that move with $s_0$ are rows of the last stage that read the stage's RK4 end state
(``last`` = 1; on the other stages they are constants far from their bound): do-mpc's
nonlinear constraints see only the stages' first knots.

This module imports neither JAX nor vehsim (the road's data arrive as arrays).
"""

from __future__ import annotations

import casadi as ca
import numpy as np
from _casadi_maneuver import axle_velocities, body_model


STATES = ("n", "xi", "vx", "vy", "r", "kappa_F", "kappa_R", "delta", "t")
INPUTS = ("rate_kappa_F", "rate_kappa_R", "rate_delta")
TVP = ("kap0", "kap1", "kap2", "grip", "n_lo", "n_hi", "mid_lo", "mid_hi", "last",
       "end_lo", "end_hi", "speed_max", "slip_max")
LF = 1.3
"""Distance [m] from the centre of gravity to the front axle (as `body_model`'s)."""
FREE = 1e3
"""A bound [m, m/s] that never binds (the terminal rows of the stages before the last)."""


def spatial_rate(X, v, k, D, B=7.0):
    r"""$dX/ds$ (CasADi) at the state ``X`` (9), the input rates ``v`` (3), the curvature
    ``k``, the tire's peak friction ``D`` and its ``B`` (numbers or symbols), and the axle
    speeds:
    $\dot s = (v_x\cos\xi - v_y\sin\xi)/(1 - n k)$, $\dot n = v_x\sin\xi + v_y\cos\xi$,
    $\dot\xi = r - k\dot s$, every rate divided by $\dot s$, $dt/ds = 1/\dot s$
    (`vehsim.spatial_rhs`)."""
    n, xi, vx, vy, r, kF, kR, d = (X[i] for i in range(8))
    body, axle_speeds = body_model(D, vx, vy, r, kF, kR, d, B)
    sdot = (vx * ca.cos(xi) - vy * ca.sin(xi)) / (1 - n * k)
    ndot = vx * ca.sin(xi) + vy * ca.cos(xi)
    return ca.vertcat(ndot, r - k * sdot, body, v * sdot, 1.0) / sdot, axle_speeds, sdot


def rk4_step(X, v, kap, D, h, B=7.0):
    """One classical RK4 step of `spatial_rate` over ``h`` with the curvature ``kap`` =
    (start, middle, end) of the step."""
    f = lambda x, k: spatial_rate(x, v, k, D, B)[0]  # noqa: E731
    k1 = f(X, kap[0])
    k2 = f(X + 0.5 * h * k1, kap[1])
    k3 = f(X + 0.5 * h * k2, kap[1])
    k4 = f(X + h * k3, kap[2])
    return X + h / 6 * (k1 + 2 * k2 + 2 * k3 + k4)


def slip_excess(X, limit):
    r"""Both axles' $\kappa_i^2V_{ix}^2 + V_{iy}^2 - \ell^2(1 + \kappa_i)^2V_{ix}^2$ at the
    state ``X`` (CasADi; $\le 0$: the combined slip within ``limit`` $\ell$)."""
    VFx, VFy, VRx, VRy = axle_velocities(X[2], X[3], X[4], X[7])
    return [k**2 * Vx**2 + Vy**2 - (limit * (1 + k)) ** 2 * Vx**2
            for k, Vx, Vy in ((X[5], VFx, VFy), (X[6], VRx, VRy))]


def stage_B(grip, stiffness_power: float | None):
    r"""The tire's $B$ on a stage of relative grip ``grip`` (a number or symbol): the
    gravel's 7, or $7 \min(g, 1)^{-q}$ with ``stiffness_power`` $q$."""
    if stiffness_power is None:
        return 7.0
    return 7.0 * ca.fmin(grip, 1.0) ** (-float(stiffness_power))


def horizon_model(H: float, M: int, D: float, stiffness_power: float | None = None):
    r"""The do-mpc discrete model (module docstring) of a horizon of length ``H`` [m] in
    ``M`` stages at the nominal peak friction ``D``, each stage's tire with the peak $D g$
    and, with ``stiffness_power`` $q$, $B = 7 \min(g, 1)^{-q}$ ($g$ the stage's ``grip``, as
    `vehsim.scaled_planning_car`); also returns the next state's expression (for the
    constraints that read it)."""
    import do_mpc

    model = do_mpc.model.Model("discrete", "SX")
    X = ca.vertcat(*(model.set_variable("_x", name) for name in STATES))
    v = ca.vertcat(*(model.set_variable("_u", name) for name in INPUTS))
    p = {name: model.set_variable("_tvp", name) for name in TVP}
    h = H / M
    nxt = rk4_step(X, v, (p["kap0"], p["kap1"], p["kap2"]), D * p["grip"], h,
                   stage_B(p["grip"], stiffness_power))
    for i, name in enumerate(STATES):
        model.set_rhs(name, nxt[i])
    model.setup()
    # setup() makes new symbols: the expressions for the MPC are rebuilt on them
    X = ca.vertcat(*(model.x[name] for name in STATES))
    v = ca.vertcat(*(model.u[name] for name in INPUTS))
    p = {name: model.tvp[name] for name in TVP}
    nxt = rk4_step(X, v, (p["kap0"], p["kap1"], p["kap2"]), D * p["grip"], h,
                   stage_B(p["grip"], stiffness_power))
    return model, X, v, p, nxt


def peak_slip(B, C: float = 1.6):
    r"""The combined slip of the tire's peak, $\tan(\pi/(2C))/B$ (``B`` a number or symbol;
    as `vehsim.FrictionEllipseTire.peak_slip`)."""
    return float(np.tan(np.pi / (2.0 * C))) / B


def end_slip_limit(p: dict, stiffness_power: float | None = None):
    r"""The slip bound at the end knot (as `vehsim.HorizonOCP.end_slip_limit`): the stage's
    ``slip_max`` or, where larger, the peak slip of the stage's tire (`stage_B`)."""
    return ca.fmax(p["slip_max"], peak_slip(stage_B(p["grip"], stiffness_power)))


def stage_rows(X, v, p: dict, nxt, h: float, limits: dict, *, steer_rate: float = 1.0,
               terminal_sideslip: float = 0.1, end_slip=None) -> dict:
    r"""The nonlinear constraints of one stage, ``{name: expression}`` with each expression
    $\le 0$ (CasADi, symbolic or numeric): at the stage's first knot ``X`` with input rates
    ``v`` and tvp row ``p`` (a dict by `TVP` name), the corridor at the node and on the
    Hermite midpoint, the axle speed floors, the steering rate and the slip bound; and the
    end node's rows on the stage's RK4 end state ``nxt`` (the corridor, the axle speeds,
    the speed, the sideslip, the slip bound ``end_slip``, by default `end_slip_limit`),
    active where ``p["last"]`` is 1 and `FREE` below their bound elsewhere. ``limits`` as
    `horizon_mpc`'s; the terminal heading and the boxes of the slips and the steering angle
    are do-mpc's bounds, not rows."""
    lim = limits

    def slope(x, k):  # dn/ds
        return spatial_rate(x, ca.DM.zeros(3), k, 1.0)[0][0]

    _, axles, sdot = spatial_rate(X, v, p["kap0"], 1.0)
    n0, n1 = X[0], nxt[0]
    n_mid = 0.5 * (n0 + n1) + h / 8 * (slope(X, p["kap0"]) - slope(nxt, p["kap2"]))
    _, axles1, _ = spatial_rate(nxt, v, p["kap2"], 1.0)
    last = p["last"]
    slips = slip_excess(X, p["slip_max"])
    end_slips = slip_excess(nxt, end_slip_limit(p) if end_slip is None else end_slip)
    return {  # name: expression <= 0
        "node_lo": p["n_lo"] - n0, "node_hi": n0 - p["n_hi"],
        "mid_lo": p["mid_lo"] - n_mid, "mid_hi": n_mid - p["mid_hi"],
        "floor_F": lim["SPEED_FLOOR"] - axles[0], "floor_R": lim["SPEED_FLOOR"] - axles[1],
        "steer_hi": v[2] * sdot - steer_rate, "steer_lo": -v[2] * sdot - steer_rate,
        "slip_F": slips[0], "slip_R": slips[1],
        # the end node, on the last stage only (elsewhere -FREE: never binds)
        "end_lo": last * (p["end_lo"] - n1) - (1 - last) * FREE,
        "end_hi": last * (n1 - p["end_hi"]) - (1 - last) * FREE,
        "end_floor_F": last * (lim["SPEED_FLOOR"] - axles1[0]) - (1 - last) * FREE,
        "end_floor_R": last * (lim["SPEED_FLOOR"] - axles1[1]) - (1 - last) * FREE,
        "end_speed": last * (nxt[2] ** 2 + nxt[3] ** 2 - p["speed_max"] ** 2)
        - (1 - last) * FREE,
        "end_slip_hi": last * (nxt[3] - terminal_sideslip * nxt[2]) - (1 - last) * FREE,
        "end_slip_lo": last * (-nxt[3] - terminal_sideslip * nxt[2]) - (1 - last) * FREE,
        "end_slip_F": last * end_slips[0] - (1 - last) * FREE,
        "end_slip_R": last * end_slips[1] - (1 - last) * FREE,
    }


def horizon_mpc(H: float, M: int, limits: dict, *, D: float = 0.52, rate_weight: float = 1e-4,
                steer_rate: float = 1.0, terminal_sideslip: float = 0.1,
                terminal_heading: float = 0.15, tol: float = 1e-6, max_iter: int = 100,
                mu_init: float | None = None, linear_solver: str = "mumps",
                warm_start: bool = True, cse: bool = True, jit: str | None = None,
                stiffness_power: float | None = None):
    """The do-mpc MPC of the horizon problem (module docstring) and a function
    ``set_horizon(tvp)`` taking the (M + 1, len(TVP)) tvp table of the current sample;
    ``stiffness_power`` that of `horizon_model`.

    ``limits``: SPEED_FLOOR, KAPPA_MIN, KAPPA_MAX, DELTA_MAX (the steering limit). IPOPT with ``linear_solver``,
    tolerance ``tol``, at most ``max_iter`` iterations, initial barrier ``mu_init`` (None:
    IPOPT's) and, with ``warm_start``, IPOPT's warm start from the previous solution and
    multipliers (do-mpc passes them). ``cse``: CasADi's common-subexpression elimination on
    the NLP's expressions (the stage's RK4 step appears both in do-mpc's dynamics and in the
    constraints that read the stage's end). ``jit``: compile the NLP's functions (objective,
    constraints, their derivatives) to machine code with CasADi's JIT through the system's C
    compiler, with these flags (e.g. "-O1"; None: CasADi's virtual machine)."""
    import do_mpc

    model, X, v, p, nxt = horizon_model(H, M, D, stiffness_power)
    h = H / M
    mpc = do_mpc.controller.MPC(model)
    opts = {"ipopt.linear_solver": linear_solver, "ipopt.print_level": 0, "ipopt.sb": "yes",
            "print_time": 0, "ipopt.tol": tol, "ipopt.max_iter": max_iter}
    if cse:
        opts["oracle_options"] = {"cse": True}
    if jit is not None:
        opts.update({"jit": True, "compiler": "shell",
                     "jit_options": {"flags": jit.split(), "verbose": False}})
    if mu_init is not None:
        opts["ipopt.mu_init"] = mu_init
    if warm_start:
        opts.update({"ipopt.warm_start_init_point": "yes",
                     "ipopt.warm_start_bound_push": 1e-6, "ipopt.warm_start_mult_bound_push": 1e-6})
    mpc.settings.n_horizon = M
    mpc.settings.t_step = h
    mpc.settings.state_discretization = "discrete"
    mpc.settings.store_full_solution = False
    mpc.settings.store_lagr_multiplier = False
    mpc.settings.store_solver_stats = ["success", "iter_count", "t_wall_total"]
    mpc.settings.nlpsol_opts = opts

    mpc.set_objective(mterm=model.x["t"], lterm=rate_weight * h * ca.sumsqr(v))
    lim = limits
    for name, lo, hi in (("kappa_F", lim["KAPPA_MIN"], lim["KAPPA_MAX"]),
                         ("kappa_R", lim["KAPPA_MIN"], lim["KAPPA_MAX"]),
                         ("delta", -lim["DELTA_MAX"], lim["DELTA_MAX"])):
        mpc.bounds["lower", "_x", name] = lo
        mpc.bounds["upper", "_x", name] = hi
        mpc.terminal_bounds["lower", name] = lo
        mpc.terminal_bounds["upper", name] = hi
    mpc.terminal_bounds["lower", "xi"] = -terminal_heading
    mpc.terminal_bounds["upper", "xi"] = terminal_heading
    mpc.settings.use_terminal_bounds = True

    cons = stage_rows(X, v, p, nxt, h, limits, steer_rate=steer_rate,
                      terminal_sideslip=terminal_sideslip,
                      end_slip=end_slip_limit(p, stiffness_power))
    for name, expr in cons.items():
        mpc.set_nl_cons(name, expr, ub=0.0)

    template = mpc.get_tvp_template()
    table = {"tvp": np.zeros((M + 1, len(TVP)))}

    def tvp_fun(t_now):
        template.master = ca.DM(table["tvp"].reshape(-1))
        return template

    mpc.set_tvp_fun(tvp_fun)
    mpc.setup()

    def set_horizon(tvp):
        table["tvp"] = np.asarray(tvp, float)

    return mpc, set_horizon


def tvp_table(curvature, grip, corridor, corridor_mid, speed_max, slip_max=None) -> np.ndarray:
    """The (M + 1, len(TVP)) tvp rows of a sample from the horizon's arrays: ``curvature``
    (M, 3) at each stage's RK4 points, ``grip`` (M,), ``corridor`` (M + 1, 2) lower/upper n
    at the nodes, ``corridor_mid`` (M, 2) at the midpoints, ``speed_max`` the terminal
    speed bound, ``slip_max`` (M,) the slip bound of each stage's first knot, the last
    stage's also of the end knot (None: `FREE`, no bound) (the row M repeats row M - 1:
    do-mpc reads it only for the terminal cost)."""
    kap = np.asarray(curvature, float)
    M = kap.shape[0]
    t = np.zeros((M + 1, len(TVP)))
    t[:M, 0:3] = kap
    t[:M, 3] = grip
    t[:M, 4:6] = np.asarray(corridor, float)[:M]
    t[:M, 6:8] = corridor_mid
    t[M - 1, 8] = 1.0
    t[:M, 9:11] = np.asarray(corridor, float)[M]
    t[:M, 11] = speed_max
    if slip_max is not None:
        slip_max = np.asarray(slip_max, float)
        if not np.all(np.isfinite(slip_max)):  # e.g. np.asarray(None): pass None itself
            raise ValueError(f"tvp_table: slip_max must be finite or None, got {slip_max}")
    t[:M, 12] = FREE if slip_max is None else slip_max
    t[M] = t[M - 1]
    return t


def set_guess(mpc, xs, us) -> None:
    """The initial guess (knots (M + 1, 9), input rates (M, 3)) of the next solve."""
    mpc.opt_x_num["_x", :, 0, -1] = [ca.DM(x) for x in np.asarray(xs, float)]
    mpc.opt_x_num["_u", :, 0] = [ca.DM(u) for u in np.asarray(us, float)]
    mpc.flags["set_initial_guess"] = True


def plan(mpc) -> tuple[np.ndarray, np.ndarray]:
    """The last solve's knots (M + 1, 9) and input rates (M, 3)."""
    xs = np.hstack([np.asarray(x) for x in mpc.opt_x_num["_x", :, 0, -1]]).T
    us = np.hstack([np.asarray(u) for u in mpc.opt_x_num["_u", :, 0]]).T
    return xs, us
