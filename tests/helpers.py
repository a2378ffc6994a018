"""Shared test helpers: tree comparison and finite-difference gradient checks."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np


def tree_allclose(x, y, *, rtol=1e-5, atol=1e-8) -> bool:
    """True if two PyTrees have the same structure and allclose leaves."""
    xl, xs = jax.tree_util.tree_flatten(x)
    yl, ys = jax.tree_util.tree_flatten(y)
    if xs != ys:
        return False
    return all(np.allclose(a, b, rtol=rtol, atol=atol) for a, b in zip(xl, yl))


def fd_grad(f, x, eps=1e-6):
    """Central finite-difference gradient of scalar ``f`` at array ``x`` (float64)."""
    x = np.asarray(x, dtype=float)
    g = np.zeros_like(x)
    flat = x.reshape(-1)
    for i in range(flat.size):
        h = eps * max(1.0, abs(flat[i]))
        xp, xm = flat.copy(), flat.copy()
        xp[i] += h
        xm[i] -= h
        g.reshape(-1)[i] = (float(f(jnp.asarray(xp.reshape(x.shape))))
                            - float(f(jnp.asarray(xm.reshape(x.shape))))) / (2 * h)
    return g


def assert_grad_matches_fd(f, x, *, rtol=1e-4, atol=1e-8, eps=1e-6):
    """Assert ``jax.grad(f)(x)`` is finite and matches central differences."""
    x = jnp.asarray(x, dtype=float)
    f = jax.jit(f)
    g = np.asarray(jax.jit(jax.grad(f))(x))
    assert np.all(np.isfinite(g)), f"non-finite gradient {g}"
    g_fd = fd_grad(f, x, eps)
    np.testing.assert_allclose(g, g_fd, rtol=rtol, atol=atol)
    return g


def module_grad_matches_fd(f, module, fields, *, rtol=1e-4, atol=1e-8, eps=1e-6):
    """Check d f(module) / d module.<field> against central differences for each named field
    (any shape), with one compiled function of all the fields' values raveled together."""
    import equinox as eqx

    values = [jnp.asarray(getattr(module, name), dtype=float) for name in fields]
    shapes = [v.shape for v in values]
    sizes = [int(np.prod(s)) for s in shapes]
    x0 = np.concatenate([np.ravel(np.asarray(v)) for v in values])

    def g(x):
        parts = jnp.split(x, np.cumsum(sizes)[:-1])
        new = [p.reshape(s) for p, s in zip(parts, shapes)]
        return f(eqx.tree_at(lambda mm: [getattr(mm, n) for n in fields], module, new))

    grad = np.asarray(jax.jit(jax.grad(g))(jnp.asarray(x0)))
    fd = fd_grad(jax.jit(g), x0, eps)
    offset = 0
    for name, size in zip(fields, sizes):
        gi, fi = grad[offset:offset + size], fd[offset:offset + size]
        offset += size
        assert np.all(np.isfinite(gi)), f"non-finite gradient wrt {name}"
        np.testing.assert_allclose(gi, fi, rtol=rtol, atol=atol, err_msg=f"gradient wrt {name}")


def one_sided_slopes(f, x, direction, h=1e-6):
    """Left and right derivatives of ``f`` (scalar or array valued) at ``x`` along
    ``direction``, each by one-sided differences at steps h and h/2 extrapolated to second
    order (Richardson): they differ where ``f`` has a kink, and agree with the derivative
    where it has one."""
    x = np.asarray(x, dtype=float)
    d = h * np.asarray(direction, dtype=float)
    val = lambda y: np.asarray(f(jnp.asarray(y)), dtype=float)  # noqa: E731
    f0 = val(x)
    right = 2 * (val(x + d / 2) - f0) / (h / 2) - (val(x + d) - f0) / h
    left = 2 * (f0 - val(x - d / 2)) / (h / 2) - (f0 - val(x - d)) / h
    return left, right
