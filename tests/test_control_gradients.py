"""Gradients through the closed braking loop: reverse mode (`jax.grad`) equals forward mode
(`jax.jvp`) equals central finite differences, for the stopping distance with respect to a
controller gain, on a short braking (3 m/s on dry asphalt, stopped within 80 samples of
5 ms) with ideal hardware and with the tuning's hardware (every effect but the tone wheel).
One compiled program per mode serves both hardware settings (array fields)."""

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest

from vehsim.control.controllers.braking import PeakSlipTracking
from vehsim.control.experiments.scenarios import braking_scenario
from vehsim.control.experiments.tuning import TUNING_HANDBACK
from vehsim.control.loop import closed_loop
from vehsim.control.plant.hardware import ideal_hardware, realistic_hardware
from vehsim.control.plant.quarter_car import SurfaceChange, change_fraction


N_STEPS = 80
HARDWARE = {"ideal": ideal_hardware(), "tuning": realistic_hardware(encoder=False)}
LOG_KP = float(np.log(PeakSlipTracking().kp))


@pytest.fixture(scope="module")
def programs():
    scenario, observer = braking_scenario("dry_asphalt", 3.0)

    def distance(log_kp, hardware):
        controller = PeakSlipTracking(kp=jnp.exp(log_kp))
        return closed_loop(scenario, controller, observer, hardware, jax.random.PRNGKey(0),
                           N_STEPS, save=False,
                           handback_speed=TUNING_HANDBACK).stopping_distance

    reverse = eqx.filter_jit(jax.value_and_grad(distance))
    forward = eqx.filter_jit(
        lambda g, hardware: jax.jvp(lambda x: distance(x, hardware), (g,), (jnp.ones(()),)))
    return reverse, forward


@pytest.mark.slow
@pytest.mark.parametrize("label", list(HARDWARE))
def test_stopping_distance_gradient_reverse_equals_forward_and_finite_differences(
        programs, label):
    reverse, forward = programs
    hardware = HARDWARE[label]
    g = jnp.asarray(LOG_KP)
    d_rev, grad_rev = (float(a) for a in reverse(g, hardware))
    d_fwd, grad_fwd = (float(a) for a in forward(g, hardware))
    h = 1e-3
    up, down = (float(forward(g + s, hardware)[0]) for s in (h, -h))
    fd = (up - down) / (2 * h)
    assert np.isfinite(d_rev) and d_rev == pytest.approx(d_fwd, rel=1e-9)
    assert np.isfinite(grad_rev) and abs(grad_rev) > 1e-5
    assert grad_rev == pytest.approx(grad_fwd, rel=1e-4)  # two programs' rounding
    assert grad_rev == pytest.approx(fd, rel=1e-3)


def test_surface_change_never_gives_zero_not_nan_cotangents():
    # a change at inf is "never": its fraction is 0 and so is its derivative, in reverse
    # mode too (the t - inf of the unused branch must not meet a zero cotangent)
    change = SurfaceChange(braking_scenario("snow")[0].car.tire)
    grad = jax.grad(lambda a: change_fraction(change, a[0], a[1], a[2]))(
        jnp.asarray([0.1, 2.0, 20.0]))
    np.testing.assert_array_equal(np.asarray(grad), 0.0)
    at = SurfaceChange(change.tire, time=jnp.asarray(0.1), length=jnp.asarray(0.25))
    grad = jax.grad(lambda a: change_fraction(at, a[0], a[1], a[2]))(jnp.asarray([0.2, 2.0, 1.0]))
    np.testing.assert_allclose(np.asarray(grad), [1.0 / 0.25, 0.0, 0.1 / 0.25])
