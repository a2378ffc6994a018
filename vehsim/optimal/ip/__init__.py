r"""A primal-dual interior-point method for stage-structured (multiple-shooting) NLPs.

The problem (`AbstractStagewiseNLP`) has stage costs, transitions $x_{k+1} = F_k(x_k, u_k)$,
path inequalities and boundary conditions at the first and last knots, each depending on one
stage only. So first and second derivatives are taken per stage (`derivatives`), and the Newton
(KKT) system is block tridiagonal (`block_tridiagonal`): it is factored by a Riccati
recursion in `lax.scan` (`riccati`), whose Cholesky factors of the control blocks exist
exactly when the inertia is right (Sylvester), which drives an IPOPT-style Hessian
regularisation (`kkt`). Inequalities get slacks and the primal-dual
barrier equations, condensed into the stage blocks. Steps obey the fraction-to-boundary rule
and a filter line search (Wächter and Biegler 2006, without restoration phase; `linesearch`);
the barrier parameter follows the monotone Fiacco-McCormick rule (`solver`). A free final time
(or any global parameter) is best carried as a state with $p_{k+1} = p_k$, which keeps the
band (a dense column coupling every defect is what ruins sparse solvers).
"""

from .derivatives import check_linear_variables as check_linear_variables
from .problem import (
    AbstractStagewiseNLP as AbstractStagewiseNLP,
    problem_sizes as problem_sizes,
)
from .solver import (
    IPLog as IPLog,
    IPOptions as IPOptions,
    IPSolution as IPSolution,
    compile_interior_point as compile_interior_point,
    interior_point as interior_point,
    print_iteration_log as print_iteration_log,
)
