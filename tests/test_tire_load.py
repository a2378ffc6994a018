import jax
import jax.numpy as jnp
import numpy as np
import pytest

import vehsim as vs


LOADS = [vs.UniformLoad(), vs.QuarticLoad(), vs.TrapezoidalLoad(ramp=0.2),
         vs.TabulatedLoad([0.0, 0.1, 0.5, 0.9, 1.0], [0.0, 2.0, 1.5, 1.0, 0.0])]


@pytest.mark.parametrize("load", LOADS, ids=lambda x: type(x).__name__)
def test_load_is_normalised_and_dq_is_its_derivative(load):
    x, w = np.polynomial.legendre.leggauss(200)
    xi = jnp.asarray(0.5 * (x + 1))
    # Piecewise shapes: integrate exactly with the trapezoid rule on a dense grid instead.
    grid = jnp.linspace(0.0, 1.0, 200001)
    total = float(jnp.trapezoid(load.q(grid), grid))
    assert abs(total - 1.0) < 1e-8
    # dq matches a central difference away from kinks
    kinks = np.asarray([float(k) for k in load.kinks()])
    pts = np.array([p for p in np.asarray(xi)[::17] if np.all(np.abs(p - kinks) > 1e-3)])
    h = 1e-6
    fd = (load.q(jnp.asarray(pts + h)) - load.q(jnp.asarray(pts - h))) / (2 * h)
    np.testing.assert_allclose(load.dq(jnp.asarray(pts)), fd, rtol=1e-6, atol=1e-6)


def test_quartic_shape_closed_form():
    xi = jnp.linspace(0, 1, 11)
    np.testing.assert_allclose(vs.QuarticLoad().q(xi), 1.25 * (1 - (2 * xi - 1) ** 4), atol=1e-13)


def test_bad_loads_raise_naming_field():
    with pytest.raises(ValueError, match="ramp"):
        vs.TrapezoidalLoad(ramp=0.7)
    with pytest.raises(ValueError, match="coefficients"):
        vs.PolynomialLoad([1.0, -3.0])  # negative near xi = 1
    with pytest.raises(ValueError, match="coefficients"):
        vs.PolynomialLoad([jnp.nan])
    with pytest.raises(ValueError, match="xi"):
        vs.TabulatedLoad([0.0, 0.6, 0.5, 1.0], [1, 1, 1, 1])


def test_polynomial_load_traceable():
    # Building inside jit must not fail on concrete-value checks.
    f = jax.jit(lambda c: vs.PolynomialLoad(c).q(jnp.asarray(0.5)))
    assert abs(float(f(jnp.array([2.0, 0.0]))) - 1.0) < 1e-14
