"""Benchmark: the interior point's sequential Riccati factorisation against a parallel-in-time one.

The structured interior point factors its block-tridiagonal KKT matrix by the backward
Riccati recursion (`vehsim.optimal.ip.riccati.riccati_factor`: one `lax.scan` over the
knots, each step a few fused small-matrix operations and an unrolled Cholesky factor of
$Q_{uu}$). Its cost on a CPU is the number of operations dispatched, about a dozen per knot.
The alternative is the parallel-in-time formulation of Särkkä and García-Fernández
("Temporal parallelization of dynamic programming and linear quadratic control", IEEE TAC
2023): each knot's Riccati map $P \\mapsto \\bar Q + \\bar A^T(I + PC)^{-1}P\\bar A$ (the
cross term removed by $R^{-1}$, the equality rows condensed as the sequential recursion
does) is an element $(\\bar A, C, \\bar Q)$ of an associative composition, so that
`jax.lax.associative_scan` gives every $P_k$ in $O(\\log M)$ levels of batched operations;
the gains and the Cholesky factors of $Q_{uu}$ (the inertia check) then follow for all knots
at once. Written here, not in the library: on one CPU core it is slower (the results file).

Both are timed on the same KKT blocks, random but of the driver's shapes ($n_x$ = 9, $n_u$ =
3, $n_e$ = 9; 31 knots is the driver's horizon of 30 stages, longer horizons beside it), as
a single factorisation and as a batch (``jax.vmap``, the Monte Carlo's form). Neither has a
data-dependent branch, so the time depends on the shapes only. Each side: best of
``--repeats`` calls after a warm-up; ``ratio`` = parallel wall time / sequential wall time
(above 1: the library's sequential recursion is the faster); ``max_rel_diff_P`` compares
the two factorisations' cost-to-go matrices. Run on one core:

    taskset -c 0 env OMP_NUM_THREADS=1 \\
      XLA_FLAGS="--xla_cpu_multi_thread_eigen=false intra_op_parallelism_threads=1" \\
      PYTHONPATH=. python experiments/benchmarks/riccati_parallel.py --out \\
      experiments/benchmarks/riccati_parallel_results.jsonl
"""

from __future__ import annotations

import argparse
import datetime
import json
import os

import jax


jax.config.update("jax_enable_x64", True)

import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402
from _common import best_time, emit, log  # noqa: E402

from vehsim.optimal.ip.block_tridiagonal import KKTMatrix  # noqa: E402
from vehsim.optimal.ip.riccati import riccati_factor  # noqa: E402


def kkt_blocks(seed: int, knots: int, nx: int = 9, nu: int = 3, ne: int = 9) -> KKTMatrix:
    """Random KKT blocks of the driver's shapes: positive definite $W_k$, transitions near
    the identity, the boundary equalities at the first knot (others padded, $d_\\nu = -1$)."""
    r = np.random.default_rng(seed)
    ny = nx + nu
    W = r.normal(size=(knots, ny, ny))
    W = np.einsum("kij,klj->kil", W, W) / ny + 0.1 * np.eye(ny)
    A = np.concatenate([np.eye(nx) + 0.1 * r.normal(size=(knots, nx, nx)),
                        0.3 * r.normal(size=(knots, nx, nu))], axis=2)
    A[-1] = 0.0
    Je = np.zeros((knots, ne, ny))
    Je[0] = r.normal(size=(ne, ny))
    de = -np.ones((knots, ne))
    de[0] = -1e-8
    dl = np.zeros((knots, nx))
    dl[-1] = -1.0
    return KKTMatrix(*(jnp.asarray(a) for a in (W, A, Je, dl, de)))


def _bmm(a, b):
    return jnp.einsum("...ij,...jk->...ik", a, b)


def _t(a):
    return jnp.swapaxes(a, -1, -2)


def _compose(earlier, later):
    """The element of ``earlier`` after ``later``: $P \\mapsto e_{earlier}(e_{later}(P))$."""
    A1, C1, J1 = earlier
    A2, C2, J2 = later
    nx = A1.shape[-1]
    M = jnp.eye(nx) + _bmm(C1, J2)
    X = jnp.linalg.solve(M, jnp.concatenate([A1, _bmm(C1, _t(A2))], axis=-1))
    A = _bmm(A2, X[..., :nx])
    C = _bmm(A2, X[..., nx:]) + C2
    J = _bmm(_t(A1), jnp.linalg.solve(_t(M), _bmm(J2, A1))) + J1
    return A, 0.5 * (C + _t(C)), 0.5 * (J + _t(J))


def parallel_factor(K: KKTMatrix):
    """$(L_k, G_k, P_{k+1})$ and the Cholesky factor of $P_0$, by the associative scan."""
    nx = K.nx
    W = K.W - jnp.einsum("kei,ke,kej->kij", K.Je, 1.0 / K.de, K.Je)
    Qw, S, R = W[:, :nx, :nx], W[:, :nx, nx:], W[:, nx:, nx:]
    Ax, Bu = K.A[:, :, :nx], K.A[:, :, nx:]
    RiSt = jnp.linalg.solve(R, _t(S))
    elems = (Ax - _bmm(Bu, RiSt), _bmm(Bu, jnp.linalg.solve(R, _t(Bu))), Qw - _bmm(S, RiSt))
    # reversed, the scan passes the later knots' element first
    _, _, P = jax.lax.associative_scan(lambda later, earlier: _compose(earlier, later), elems,
                                       reverse=True)
    P_next = jnp.concatenate([P[1:], jnp.zeros((1, nx, nx))])
    Q = W + jnp.einsum("kji,kjl,klm->kim", K.A, P_next, K.A)
    L = jnp.linalg.cholesky(Q[:, nx:, nx:])
    G = jax.scipy.linalg.cho_solve((L, True), Q[:, nx:, :nx])
    return L, G, P_next, jnp.linalg.cholesky(P[0])


def sequential_factor(K: KKTMatrix):
    F = riccati_factor(K)
    return F.L, F.G, F.P, F.L0


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--knots", type=int, nargs="+", default=[31, 61, 121])
    ap.add_argument("--batch", type=int, default=256)
    ap.add_argument("--repeats", type=int, default=200)
    ap.add_argument("--out", default=None)
    args = ap.parse_args()
    base = dict(benchmark="riccati_parallel", date=datetime.date.today().isoformat(),
                device=jax.devices()[0].device_kind, cpus=os.cpu_count())
    rows = []
    for knots in args.knots:
        for batch in (None, args.batch):
            Ks = [kkt_blocks(seed, knots) for seed in range(batch or 1)]
            K = Ks[0] if batch is None else jax.tree.map(lambda *a: jnp.stack(a), *Ks)
            wrap = (lambda f: f) if batch is None else jax.vmap
            seq, par = jax.jit(wrap(sequential_factor)), jax.jit(wrap(parallel_factor))
            Fs, Fp = seq(K), par(K)
            diff = float(jnp.max(jnp.abs(Fp[2] - Fs[2])) / jnp.max(jnp.abs(Fs[2])))
            reps = max(5, args.repeats // (batch or 1) * 4)
            t_seq, t_par = best_time(seq, K, repeats=reps), best_time(par, K, repeats=reps)
            rec = dict(base, knots=knots, batch=batch or 1, sequential_us=t_seq * 1e6,
                       parallel_us=t_par * 1e6, ratio=t_par / t_seq, max_rel_diff_P=diff)
            emit(**rec)
            rows.append(rec)
    if args.out:
        with open(args.out, "a") as f:
            for rec in rows:
                f.write(json.dumps(rec) + "\n")
        log(f"appended {len(rows)} rows to {args.out}")


if __name__ == "__main__":
    main()
