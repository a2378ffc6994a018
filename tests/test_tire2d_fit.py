"""The fitted 2D LuGre preset: its documented residual, and that it is a least-squares optimum."""

import jax
import jax.numpy as jnp
import numpy as np

from vehsim.params import bakker1987, lugre2d_bakker1987
from vehsim.tire.lugre2d_fit import _pack, _unpack, default_slip_grid, match_residuals


def test_preset_residual_and_stationarity():
    p, mf = lugre2d_bakker1987(), bakker1987()
    kappa, alpha = default_slip_grid()

    @jax.jit
    def residuals(theta):
        return match_residuals(_unpack(theta, p), mf, 4000.0, 20.0, kappa, alpha)

    theta = _pack(p)
    r = residuals(theta)
    # the numbers in the preset's docstring
    np.testing.assert_allclose(jnp.sqrt(jnp.mean(r**2)), 0.0142, atol=5e-5)
    np.testing.assert_allclose(jnp.max(jnp.abs(r)), 0.0290, atol=5e-5)
    # Levenberg-Marquardt stopped at a stationary point of 1/2 |r|^2 (gradient J^T r ~ 0,
    # relative to |J| |r|), and small steps in any parameter only make the fit worse.
    J = jax.jacfwd(residuals)(theta)
    grad = J.T @ r
    assert np.max(np.abs(grad)) < 1e-5 * np.linalg.norm(J) * np.linalg.norm(r)
    for i in range(theta.shape[0]):
        for h in (-1e-2, 1e-2):
            worse = residuals(theta.at[i].add(h))
            assert jnp.sum(worse**2) >= jnp.sum(r**2)
