"""Reduced half-car (eqs. 61-63) with the benchmark maneuvers' quasi-static load transfer (docs/maneuvers.md)."""

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from helpers import module_grad_matches_fd

from vehsim import LinearTire, ReducedHalfCar, preset, rally_gravel, rally_gravel_tire


def _model():
    return ReducedHalfCar(rally_gravel(), rally_gravel_tire())


STATE = jnp.array([1.0, -2.0, 0.4, 14.0, -1.5, 0.3])
CONTROLS = jnp.array([-0.08, 0.15, 0.2])


def test_loads_solve_the_spec_2x2_system_exactly():
    model = _model()
    p = model.params
    for u in [CONTROLS, jnp.array([-0.5, -0.3, -0.1]), jnp.array([0.6, 0.9, 0.5])]:
        FzF, FzR = model.normal_loads(STATE, u)
        VFx, VFy, VRx, VRy = model.axle_velocities(STATE, u[2])
        mFx, mFy = model.tire.mu(u[0], VFy / VFx)
        mRx, _ = model.tire.mu(u[1], VRy / VRx)
        muF_bx = mFx * jnp.cos(u[2]) - mFy * jnp.sin(u[2])
        A = np.array([[1.0, 1.0], [-(p.lF + p.h * muF_bx), p.lR - p.h * mRx]])
        b = np.array([p.m * p.g, 0.0])
        np.testing.assert_allclose([FzF, FzR], np.linalg.solve(A, b), rtol=1e-12)
    # braking moves load to the front, driving to the rear; zero slip straight: eqs. 57-58
    straight = jnp.array([0.0, 0.0, 0.0, 15.0, 0.0, 0.0])
    F0 = p.static_loads()
    np.testing.assert_allclose(model.normal_loads(straight, jnp.zeros(3)), F0, rtol=1e-12)
    assert model.normal_loads(straight, jnp.array([-0.1, -0.1, 0.0]))[0] > F0[0]
    assert model.normal_loads(straight, jnp.array([0.1, 0.1, 0.0]))[0] < F0[0]
    assert preset("rally_gravel").lR == 1.4


def test_vector_field_is_eqs_61_63():
    """Body-frame rates, rotated back, give the inertial eqs. 61-62 and eq. 63."""
    model = _model()
    p = model.params
    x, y, psi, vx, vy, r = STATE
    d = CONTROLS[2]
    dot = model.f(STATE, CONTROLS)
    fF, fR = model.tire_forces(STATE, CONTROLS)
    c, s = jnp.cos(psi), jnp.sin(psi)
    xdd = dot[3] * c - vx * s * r - dot[4] * s - vy * c * r
    ydd = dot[3] * s + vx * c * r + dot[4] * c - vy * s * r
    e61 = (fF[0] * jnp.cos(psi + d) - fF[1] * jnp.sin(psi + d)
           + fR[0] * jnp.cos(psi) - fR[1] * jnp.sin(psi)) / p.m
    e62 = (fF[0] * jnp.sin(psi + d) + fF[1] * jnp.cos(psi + d)
           + fR[0] * jnp.sin(psi) + fR[1] * jnp.cos(psi)) / p.m
    e63 = ((fF[1] * jnp.cos(d) + fF[0] * jnp.sin(d)) * p.lF - fR[1] * p.lR) / p.Iz
    np.testing.assert_allclose([xdd, ydd, dot[5]], [e61, e62, e63], rtol=1e-12)
    np.testing.assert_allclose(dot[:3], [vx * jnp.cos(psi) - vy * jnp.sin(psi),
                                         vx * jnp.sin(psi) + vy * jnp.cos(psi), r], rtol=1e-12)
    # free rolling on a straight: no force, no acceleration
    straight = jnp.array([0.0, 0.0, 0.0, 15.0, 0.0, 0.0])
    np.testing.assert_allclose(model.f(straight, jnp.zeros(3)), [15.0, 0, 0, 0, 0, 0], atol=1e-12)


def test_recovered_torques_satisfy_wheel_equations():
    """omega = (1+kappa)Vx/r, T = I domega/dt + fx r (eqs. 52-53); d/dt by central differences."""
    model = _model()
    p = model.params
    u_dot = jnp.array([0.3, -0.2, 0.5])
    omF, omR, TF, TR = model.recover_torques(STATE, CONTROLS, u_dot)
    np.testing.assert_allclose([omF, omR], model.wheel_speeds(STATE, CONTROLS), rtol=1e-14)
    eps = 1e-6
    ydot = model.f(STATE, CONTROLS)
    wp = np.array(model.wheel_speeds(STATE + eps * ydot, CONTROLS + eps * u_dot))
    wm = np.array(model.wheel_speeds(STATE - eps * ydot, CONTROLS - eps * u_dot))
    om_dot = (wp - wm) / (2 * eps)
    fF, fR = model.tire_forces(STATE, CONTROLS)
    np.testing.assert_allclose(TF, p.Iw_F * om_dot[0] + fF[0] * p.r, rtol=1e-7)
    np.testing.assert_allclose(TR, p.Iw_R * om_dot[1] + fR[0] * p.r, rtol=1e-7)


def test_vmap_jit_grad():
    model = _model()
    us = jnp.stack([CONTROLS * s for s in (0.5, 1.0, -1.0)])
    batch = jax.jit(jax.vmap(model.f, in_axes=(None, 0)))(STATE, us)
    for u, b in zip(us, batch):
        np.testing.assert_allclose(b, model.f(STATE, u), rtol=1e-13)
    for i in (3, 4, 5):
        module_grad_matches_fd(lambda p: model.__class__(p, model.tire).f(STATE, CONTROLS)[i],
                               model.params, ["m", "Iz", "lF", "h"])
        module_grad_matches_fd(lambda t: ReducedHalfCar(model.params, t).f(STATE, CONTROLS)[i],
                               model.tire, ["B", "C", "D"])
    g = jax.grad(lambda u: jnp.sum(model.f(STATE, u)[3:] ** 2))(jnp.zeros(3))
    assert np.all(np.isfinite(g))


def test_linear_tire_and_invalid_tire():
    model = ReducedHalfCar(rally_gravel(), LinearTire(c_kappa=10.0, c_alpha=8.0))
    fF, fR = model.tire_forces(STATE, CONTROLS)
    FzF, FzR = model.normal_loads(STATE, CONTROLS)
    np.testing.assert_allclose(fR[0], 10.0 * FzR * CONTROLS[1], rtol=1e-12)

    class _Dyn(LinearTire):
        def init_state(self):
            return jnp.zeros((1,))

    with pytest.raises(ValueError, match="static"):
        ReducedHalfCar(rally_gravel(), _Dyn(c_kappa=1.0, c_alpha=1.0))


CONTROL_SET = (CONTROLS, jnp.array([-0.5, -0.3, -0.1]), jnp.array([0.6, 0.9, 0.5]))


def _assert_same_car(a, b, u, *, rtol, atol, jac_rtol, jac_atol):
    """Cars ``a`` and ``b`` give the same loads, tire forces (``atol`` [N]), rates and the
    rates' Jacobians at `STATE` and controls ``u``."""
    np.testing.assert_allclose(a.normal_loads(STATE, u), b.normal_loads(STATE, u), rtol=rtol)
    for fa, fb in zip(a.tire_forces(STATE, u), b.tire_forces(STATE, u)):
        np.testing.assert_allclose(fa, fb, rtol=rtol, atol=atol)
    np.testing.assert_allclose(a.f(STATE, u), b.f(STATE, u), rtol=rtol, atol=1e-12)
    for argnum in (0, 1):
        np.testing.assert_allclose(jax.jacfwd(a.f, argnum)(STATE, u),
                                   jax.jacfwd(b.f, argnum)(STATE, u), rtol=jac_rtol,
                                   atol=jac_atol)


def test_load_proportional_tires_give_the_load_transfer_iteration_s_model():
    """Load-proportional tires are evaluated at unit load, not per load: the loads, forces,
    rates and the rates' Jacobian equal those of the general path (the tire at the static
    loads, the 2x2 load transfer, the tire again at the solved loads) to rounding."""
    for tire in (rally_gravel_tire(), LinearTire(c_kappa=10.0, c_alpha=8.0)):
        class General(type(tire)):
            load_proportional = False

        fast = ReducedHalfCar(rally_gravel(), tire)
        general = ReducedHalfCar(rally_gravel(), General(**{f.name: getattr(tire, f.name)
                                                             for f in dataclasses.fields(tire)}))
        assert fast.tire.load_proportional and not general.tire.load_proportional
        for u in CONTROL_SET:
            _assert_same_car(fast, general, u, rtol=1e-13, atol=1e-9, jac_rtol=1e-11,
                             jac_atol=1e-9)


def test_one_tire_on_both_axles_is_evaluated_once_for_the_pair():
    """A car whose two axles share one load-proportional tire (no `tire_R`) evaluates it
    once, over the pair of axles: the traced program holds one tire evaluation, not two
    (what makes the solvers' compiled derivatives cheaper), and the loads, forces, rates
    and the rates' first and second derivatives equal those of the same tire given for
    each axle (`tire_R`), which evaluates it per axle, to rounding."""
    for tire in (rally_gravel_tire(), LinearTire(c_kappa=10.0, c_alpha=8.0)):
        calls = []

        class Counted(type(tire)):
            def forces(self, state, vx, vy, omega, r, Fz):
                calls.append(jnp.shape(vx))
                return super().forces(state, vx, vy, omega, r, Fz)

        counted = Counted(**{f.name: getattr(tire, f.name) for f in dataclasses.fields(tire)})
        shared = ReducedHalfCar(rally_gravel(), counted)
        apart = ReducedHalfCar(rally_gravel(), counted, tire_R=counted)
        for model, traced in ((shared, [()]), (apart, [(), ()])):
            calls.clear()
            jax.make_jaxpr(model.f)(STATE, CONTROLS)
            assert calls == traced, (type(tire).__name__, calls)
        weights = jnp.array([0.3, -1.1, 0.7, 1.9, -0.4, 2.3])
        for u in CONTROL_SET:
            _assert_same_car(shared, apart, u, rtol=1e-14, atol=1e-10, jac_rtol=1e-12,
                             jac_atol=1e-10)
            hess = [jax.hessian(lambda x, m=m: weights @ m.f(x[:6], x[6:]))(
                jnp.concatenate([STATE, u])) for m in (shared, apart)]
            np.testing.assert_allclose(hess[0], hess[1], rtol=1e-11, atol=1e-9)
