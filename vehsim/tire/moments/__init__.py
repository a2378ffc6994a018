r"""Aggregate dynamics of the distributed 2D LuGre model by the method of moments (eqs. 39-48).

In $\xi = \zeta/L$ the moments of eq. 39 over a piece $[a, b]\subset[0, 1]$ are
$m^{ab}_{p,i}(t) = \int_a^b z_i(t,\xi)\,\xi^p\,d\xi$ and, since $v_r$, $C_{0i}$ and the
transport speed $c = |\omega r|$ are uniform over the patch, eq. 31a integrated by parts gives
the recursion of eqs. 41-42 ($p\ge0$, the last term absent for $p=0$):
$$\dot m^{ab}_{p,i} = \frac{b^{p+1}-a^{p+1}}{p+1}v_{ri} - C_{0i}m^{ab}_{p,i}
  - \frac cL\bigl(z_i(t,b)\,b^p - z_i(t,a)\,a^p\bigr) + \frac cL\,p\,m^{ab}_{p-1,i}.$$
A load that is polynomial on pieces, $q(\xi) = \sum_k c^{(j)}_k\xi^k$ on $[e_j, e_{j+1}]$
(eq. 43; one piece for uniform, quartic or any `PolynomialLoad`, three for the trapezoid),
gives the forces and moment exactly in terms of the moments (eqs. 46, 48, our sign):
$$\frac{F_i}{F_n} = \sum_j\sum_k c^{(j)}_k\bigl(\sigma_{0i}m^{(j)}_{k,i}
  + \sigma_{1i}\dot m^{(j)}_{k,i}\bigr) + \sigma_{2i}v_{ri},$$
$$\frac{M_z}{F_nL} = \sum_j\sum_k c^{(j)}_k\Bigl(\sigma_{0y}
  \bigl(\tfrac12m^{(j)}_{k,y} - m^{(j)}_{k+1,y}\bigr)
  + \sigma_{1y}\bigl(\tfrac12\dot m^{(j)}_{k,y} - \dot m^{(j)}_{k+1,y}\bigr)\Bigr)
  + \sigma_{2y}v_{ry}\int_0^1q\,(\tfrac12-\xi)\,d\xi .$$
So moments up to degree $m+1$ per piece are needed, and the recursion is closed *except*
for the boundary values $z_i(t, e_j)$ at the piece edges.

**Basis.** The same system can be written against any basis of the polynomials of degree
$< K$ on each piece (`basis_tables`); only the linear maps change, and exactness does not.
The default is the shifted Legendre polynomials of each piece,
$\mu^{(j)}_{k,i} = \int_0^1 z_i(t, e_j + h_jx)\tilde P_k(x)\,dx$, $h_j = e_{j+1}-e_j$:
eq. 41 becomes
$\dot\mu_k = v_r\delta_{k0} - C_0\mu_k - \frac{c}{Lh}\bigl(z(t,e_{j+1}) - (-1)^kz(t,e_j)
- \sum_{l<k,\ k-l\ \text{odd}}2(2l+1)\mu_l\bigr)$ (from $\tilde P_k(1) = 1$,
$\tilde P_k(0) = (-1)^k$ and $\tilde P_k'$ in the basis), and eqs. 46/48 take the Legendre
coefficients of $q$ and of $q(\tfrac12-\xi)$ per piece, $O(1)$ where the monomial
coefficients alternate ($30, -60, 30$ for the quartic). `basis="monomial"` is eq. 41
verbatim. Both agree to solver tolerance; the Legendre form is the better conditioned
state for the solver's error control, but the amplification of edge errors below is a
property of the truncated system, the same in every basis.

**The boundary terms (eqs. 41-42).** At the leading edge $z(t,0) = 0$. At an edge $e>0$ (an
interface or the trailing edge $e=1$) the value is tracked by a characteristic argument. The
PDE is transport at speed $c/L$ of a point-model ODE whose coefficients do not depend on
$\xi$; let $s(t) = \int_0^t c/L$ be the distance travelled by the tread since $t=0$
(in patch lengths) and $t_e(t)$ the time at which the tread now at $e$ entered the patch
($s(t) - s(t_e) = e$). Differentiating
$z(t,e) = \int_{t_e}^t e^{-\int_\tau^tC_0}v_r(\tau)\,d\tau$ (for $s \ge e$) gives the exact
edge equation
$$\dot z_e = v_r - C_0\,z_e - H(s - e)\,\dot t_e\,e^{-\int_{t_e}^tC_0}\,v_r(t_e),$$
whose last term is the deflection-free tread arriving from the leading edge. Before the
first passage ($s < e$) the tread at $e$ was in the patch at $t = 0$; for a uniform initial
deflection (zero, or a locked wheel's state) it obeys the point model, which is the same
equation without the last term.

The only term that is not a function of the current state and inputs is the *delayed*
arrival term (with $C_0 = 0$ the trailing edge obeys $\dot z(t,1) = v_r(t) - v_r(t_e)$, a
delay equation), so no finite state closes it for arbitrary inputs. But the edge values
are functionals of the *input history alone* (the coefficients $v_r$, $C_0$, $c$ do not
depend on $z$), which gives these closures of eqs. 41-42:

- **Exact, delay states** (`simulate_moments_delay`, for inputs known in advance: the
  transients of Fig. 17, a recorded manoeuvre). The entry time obeys
  $\dot t_e = c(t)/c(t_e)$ (from $s(t) - s(t_e) = e$), and the inputs can be evaluated at
  $t_e$, so $t_e$, $D_e = \int_{t_e}^tC_0$ ($\dot D_e = C_0(t) - \dot t_eC_0(t_e)$) and
  $z_e$ with its exact edge equation are ODE states beside the moments, switched on at the
  first passage $t_p$ ($s(t_p) = e$, found beforehand by Newton on a Gauss quadrature of
  $c/L$). The moment system then reproduces the PDE for any rolling input history up to
  solver tolerance. Needs $c(t_e) > 0$: tread that entered while the wheel was locked
  needs the history closure.
- **Exact, history** (`simulate_moments_history`): a first solve integrates five history
  states (tread travelled, $\int C_0$, and the point model from rest) with dense output, and
  `TransitHistory` returns the exact $z_i(t, e)$ at every edge from them and the entry
  time found by safeguarded Newton (locked phases included). Each right-hand side then
  searches the dense output, which makes it the slower of the two.
- **Exact, solved in closed form** (`moments_step_response`, for a step in slip: inputs
  constant from $t_0$ on, from a uniform deflection): between passages over the piece
  edges the whole system is linear with constant coefficients and a nilpotent coupling,
  so it is solved exactly by finite sums (no time stepping): the transients of Fig. 17 at
  the cost of a few dozen small array operations, and exactly steady after one transit.
- **Online** (`MomentLuGre2D` as an `AbstractTire` inside a vehicle, where the inputs
  depend on the state): we carry $z_e$ for every edge and $s$ as states, with the arrival
  term evaluated with the inputs frozen over the transit ($\dot t_e = 1$,
  $e^{-\int C_0} = e^{-C_0eL/c}$, $v_r(t_e) = v_r(t)$; zero for a locked wheel, $c = 0$).
  This is exact whenever the inputs are constant since the last passage began: for a slip
  step from a uniform deflection the whole moment system is exact at all times, and at
  every steady state $z_e = \frac{v_rL}{c}e\,\varphi(\frac{C_0L}{c}e)$,
  $\varphi(x) = (1-e^{-x})/x$, the closed form. Otherwise it errs through the arrival
  term, damped by $e^{-C_0eL/c}$.

**Conditioning, and the kink at first passage.** Loads that vanish at the trailing edge
(quartic, trapezoid) do not escape the edge values: the force combination has no
trailing-edge term, but the chain $q\to q'\to\dots\to$ const of lower moments it needs ends
in $m_0$, whose equation (42) carries $z(t,1)$. The interior of the PDE never depends on the
outflow value $z(t,1)$, but the truncated moment system does: an error $\delta$ in it
reaches $m_p$ with steady gain $\sum_{j\le p}\frac{p!}{j!}\bigl(\frac{c}{LC_0}\bigr)^{p-j+1}$,
large for the quartic at small slip angles, in any basis. The edge values are continuous
but kink where fresh tread first reaches the edge ($t = t_p$); a step across that kink
leaves a local error of the order of the step in $z_e$, which this gain makes the dominant
error. Landing a step on $t_p$ (a `jump_ts` of the solver, with the switch written in $t$
so that it falls exactly between steps) removes it. The online closure cannot land on its
switch (it depends on the state), and needs tight tolerances.

**Files.** `basis` (load pieces, basis tables, the coupling matrix), `model`
(`MomentLuGre2D`, the online closure), `closures` (`simulate_moments_delay` and
`simulate_moments_history`: the delay and history closures, `TransitHistory`,
`passage_times`), `step_response` (`moments_step_response`).
Accuracy and cost are measured in `docs/performance.md`.
"""

from .basis import (
    BASES as BASES,
    basis_tables as basis_tables,
    coupling_matrix as coupling_matrix,
    legendre_tables as legendre_tables,
    piecewise_coefficients as piecewise_coefficients,
)
from .closures import (
    HISTORY_MAX_STEPS as HISTORY_MAX_STEPS,
    TransitHistory as TransitHistory,
    passage_times as passage_times,
    simulate_moments_delay as simulate_moments_delay,
    simulate_moments_history as simulate_moments_history,
)
from .model import MomentLuGre2D as MomentLuGre2D
from .step_response import (
    decay_integrals as decay_integrals,
    moments_step_response as moments_step_response,
)
