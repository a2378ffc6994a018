r"""Named drive scenarios: a centre-line road, the grip on it, the plant and where it starts.

**Roads** (`scenario_road`), all `vehsim.CentrelineRoad`s with full-width gates at both ends
and the speed free there:

- `corner90`, `uturn`, `sturn`: the benchmark corners of docs/maneuvers.md (report Table 4)
  as roads of the benchmark's width, 2 m ($\pm 1$ m about the legs' centre lines), the legs'
  centre lines joined by circular arcs of radius `BENCHMARK_ARC_RADIUS` (4 m; the boundary
  folds at $|n\kappa| = 1$, here $1/4$). The start and end gates are the benchmark's: corner90
  from $x = -5$ ($8 \le y \le 10$, heading 0) to $y = -5$ ($8 \le x \le 10$, heading
  $-\pi/2$); uturn from $y = -5$ on the left leg ($-10 \le x \le -8$, heading $\pi/2$) to
  $y = -5$ on the right leg, through the top leg $8 \le y \le 10$; sturn from $x = -14$
  ($-10 \le y \le -8$) to $x = 14$ ($8 \le y \le 10$) through the connector
  $-1 \le x \le 1$. The straight parts of the legs coincide with the benchmark's; at a corner
  the road is the arc's annulus instead of the legs' square union: it reaches
  $\sqrt2(R - 1) - (R - 1)$ = 1.24 m past the benchmark's inner corner point (along the
  diagonal) and leaves out $\sqrt2(R + 1) - (R + 1)$ = 2.07 m of its outer corner, so
  times are not comparable with the benchmark's.
- `stage`: a gravel stage of 211 m, 4 m wide ($\pm 2$ m), with left and right corners of
  radii 15-40 m and a 10 m hairpin (180 degrees), from the origin heading along $x$.

**Grip** (`scenario_grip`): the plant's tire (`LumpedLuGre2D` with `lugre2d_bakker1987`) on a
road of friction scale $\lambda$ (`vehsim.scale_friction`) has the peak friction
$\mu^*(\lambda)$ = `AxleGripEstimator().peak(lambda)` (`plant_peak`; the largest steady-state
friction in braking at 20 m/s): 1.1174 at $\lambda = 1$. The peak is *not* proportional to
$\lambda$ (the lumped model's edge term $\kappa c$ does not scale): $\mu^*(\lambda)/\lambda$
is 1.30 at $\lambda = 0.4$, 1.12 at 1, so $0.52/\mu^*(1) = 0.465$ would give a peak of 0.59.
Each scenario is therefore given by its peaks, and its scales solve $\mu^*(\lambda) = $ the
peak (`scale_for_peak`, bisection): $\lambda_0$ (`nominal_scale`, 0.400) has the benchmark's
$D = 0.52$.

- `nominal`: peak 0.52 everywhere;
- `minus20`: peak $0.8 \times 0.52$ everywhere (a planner that assumes 0.52 overestimates
  it by 25 %);
- `icy`: a circular patch of peak $0.5 \times 0.52$ ($\tanh$ edge of 1 m, as
  `GripPatches`) centred on the apex of the road's main corner (corner90's corner, the first
  corner of uturn and sturn, the stage's hairpin), radius 3 m on the benchmark corners, 8 m
  on the stage, on the nominal road; on any other road (one read from a file, even if named
  like a scenario road), radius 3 m at $s = L/2$;
- `rising`: peak $0.6 \times 0.52$ at the start rising to 0.52 at a third of the road (a
  `GripProfile` along the direction from the start to the end of the road, its stations
  those of the start and of the centre line at $s = L/3$; on these roads the centre line
  never comes back below that station, so the grip along it rises monotonically). A closed
  road, or one whose centre line at $s = L/3$ lies behind its start on that line, is
  refused.

All these peaks are stated at 20 m/s (`REFERENCE_SPEED`, the estimator's
`reference_speed`): the LuGre peak rises as the speed falls (eq. 21), so at the corners'
speeds of 3-8 m/s the same roads have peaks 15-25 % higher (the nominal road: 0.60 at
8 m/s, 0.65 at 4 m/s; `peak_friction`). The drivers plan with the peak at the speed they
drive (`RecedingHorizonDriver`).

Every scenario's field is a `PatchedProfile` (a two-station profile times one patch; a
uniform road has equal stations' scales, no patch a factor of 1), so that the plants of all
scenarios have one structure: one compilation serves them, and they batch in one `vmap`.
`ScenarioGrip.peak` is the true peak $\mu^*(\lambda(c(s)))$ at 20 m/s along the centre
line (the offline bound's friction); the oracle driver reads the scale (the table's
`scale` column) and takes its peak at each stage's speed.

**The drive** (`drive_scenario`): the `DrivePlant` on that grip (default actuators and
sensors), starting on the centre of the start gate heading along the road at the stated
`START_SPEEDS` (chosen so that the minimum-time drive starting there stays feasible on
every grip scenario), with a time budget of `TIME_BUDGETS` seconds at the plant's 20 Hz.
"""

from __future__ import annotations

import functools
import math

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from .._fields import array_field
from .._math import safe_hypot
from ..optimal.centreline import CentrelineRoad, Gate
from ..tire.base import AbstractTire
from ..tire.friction_ellipse import FrictionEllipseTire
from ..tire.mf6 import MFParams
from .actuators import DriveActuators
from .axle_peak import AxlePeakEstimator, CautiousGripEstimator
from .estimator import AbstractGripEstimator, AxleGripEstimator, scale_of_peak
from .grip import (
    AbstractGripField,
    GripPatches,
    GripProfile,
    PeakRatios,
    RelativeGrip,
    SurfaceFactor,
)
from .horizon import RecedingHorizonDriver, RoadTable
from .plant import DrivePlant, DriveState, init_drive
from .plant_tires import peak_surface_factor
from .sensors import DriveSensors


BENCHMARK_PEAK = 0.52
"""Peak friction $D$ of the benchmark's gravel (docs/maneuvers.md), the planner's nominal."""

BENCHMARK_ARC_RADIUS = 4.0
"""Radius [m] of the arcs that join the benchmark corners' legs."""

BENCHMARK_WIDTH = 2.0
"""Width [m] of the benchmark corners' roads (docs/maneuvers.md)."""

STAGE_WIDTH = 4.0
"""Width [m] of the rally stage."""

_R = BENCHMARK_ARC_RADIUS
_ROADS = {
    # start point, start heading, segments, width, index of the main corner's segment,
    # radius of the icy patch [m]
    "corner90": ((-5.0, 9.0), 0.0,
                 (("straight", 14.0 - _R), ("arc", _R, -90.0), ("straight", 14.0 - _R)),
                 BENCHMARK_WIDTH, 1, 3.0),
    "uturn": ((-9.0, -5.0), math.pi / 2,
              (("straight", 14.0 - _R), ("arc", _R, -90.0), ("straight", 18.0 - 2 * _R),
               ("arc", _R, -90.0), ("straight", 14.0 - _R)),
              BENCHMARK_WIDTH, 1, 3.0),
    "sturn": ((-14.0, -9.0), 0.0,
              (("straight", 14.0 - _R), ("arc", _R, 90.0), ("straight", 18.0 - 2 * _R),
               ("arc", _R, -90.0), ("straight", 14.0 - _R)),
              BENCHMARK_WIDTH, 1, 3.0),
    "stage": ((0.0, 0.0), 0.0,
              (("straight", 20.0), ("arc", 30.0, 40.0), ("straight", 12.0),
               ("arc", 20.0, -80.0), ("straight", 15.0), ("arc", 10.0, 180.0),
               ("straight", 12.0), ("arc", 15.0, -110.0), ("straight", 12.0),
               ("arc", 40.0, -30.0), ("straight", 10.0)),
              STAGE_WIDTH, 5, 8.0),
}

ROAD_NAMES = tuple(_ROADS)
"""The scenario roads."""

GRIP_NAMES = ("nominal", "minus20", "icy", "rising")
"""The grip scenarios."""

START_SPEEDS = {"corner90": 8.0, "uturn": 7.0, "sturn": 7.0, "stage": 12.0}
"""Speed [m/s] at the start gate of each road's drives."""

TIME_BUDGETS = {"corner90": 6.0, "uturn": 9.0, "sturn": 9.0, "stage": 30.0}
"""Time budget [s] of each road's drives."""

MAX_START_SPEED = 80.0
"""The highest start speed [m/s] `drive_scenario` takes: the planners' speed cap
(`vehsim.optimal.curvilinear.SPEED_CAP`), 288 km/h."""

MAX_TIME_BUDGET = 3600.0
"""The longest time budget [s] `drive_scenario` takes: an hour, 72,000 samples at 20 Hz,
whose record a drive keeps in memory."""

MINUS20_PEAK = 0.8
"""The `minus20` road's peak friction, a fraction of 0.52."""

PATCH_PEAK = 0.5
"""The icy patch's peak friction, a fraction of 0.52."""

RISING_START = 0.6
"""The rising grip's peak friction at the start, a fraction of 0.52."""


def _check_name(kind: str, name, allowed) -> None:
    if name not in allowed:
        raise ValueError(f"unknown {kind} {name!r}; allowed: {', '.join(allowed)}")


def scenario_road(name: str) -> CentrelineRoad:
    """The scenario road called `name` (`ROAD_NAMES`: corner90, uturn, sturn, stage; module
    docstring), gates at both ends (full width, speed free)."""
    _check_name("road", name, ROAD_NAMES)
    start, heading, segments, width, _, _ = _ROADS[name]
    return CentrelineRoad.from_segments(list(segments), width, start_heading=heading,
                                        start=start, name=name)


def main_corner(name: str) -> tuple[float, float]:
    """Arc lengths [m] where the main corner of road `name` begins and ends."""
    _check_name("road", name, ROAD_NAMES)
    _, _, segments, _, index, _ = _ROADS[name]
    lengths = [seg[1] if seg[0] == "straight" else seg[1] * math.radians(abs(seg[2]))
               for seg in segments]
    s0 = float(sum(lengths[:index]))
    return s0, s0 + float(lengths[index])


DRIVER_TRACTION_LIMIT = 0.9
"""`RecedingHorizonDriver.traction_limit` of every `driver_settings`: the axle torques ask
at most 90 % of the longitudinal force the plant's tire can give at the planned velocity."""

CORNER_DRIVER = {"margin": 0.4, "margin_grip_power": 1.0,
                 "traction_limit": DRIVER_TRACTION_LIMIT}
"""`RecedingHorizonDriver` settings of `driver_settings` on the benchmark corners."""

FAST_ROAD_DRIVER = {"margin": 0.3, "iterations": 10, "hessian_update": "first",
                    "peak_fraction": 0.9, "traction_limit": DRIVER_TRACTION_LIMIT,
                    "replan_kkt": 100.0, "replan_iterations": 20}
"""`RecedingHorizonDriver` settings of `driver_settings` on the stage: a corridor margin,
more passes (10, each sample's first Hessian kept for its later ones), a lost plan (KKT
residual past 100) planned again from the cold start in at most 20 passes, and a friction
margin."""

FILE_ROAD_DRIVER = FAST_ROAD_DRIVER | {
    "iterations": 16, "replan_iterations": 40, "margin": 0.5, "terminal_backoff": 0.85,
    "slip_limit": 0.1, "corridor_penalty": 1.0}
"""`RecedingHorizonDriver` settings of `driver_settings` on a road from a file: more passes
than the stage's (16, each sample's first Hessian kept), the stage's friction margin, a
lost plan planned again in at most 40 passes, a wider corridor margin, a lower terminal
speed bound, a tighter slip bound for the plant's tire at speed and a soft corridor
(measured on the shipped circuit)."""

_CORNERS = ("corner90", "uturn", "sturn")

CONVERGED_REPLAN_KKT = 100.0
"""`RecedingHorizonDriver.replan_kkt` of `driver_settings` in converged mode where the
road's settings have none (the benchmark corners; the stage's and a road file's are also
100): a solve that ends past it, unconverged at its cap, is no plan to shift, and the next
sample plans again from the cold start."""

DRIVER_PROBE_DISTANCE = 2.0
"""`RecedingHorizonDriver.probe_distance` [m] of `driver_settings` for the driver with the
estimate on the benchmark corners: a test brake of the front axle on the first 2 m
(`RecedingHorizonDriver.probe_direction` 'brake')."""


def driver_settings(name: str | None, friction: str | None = None,
                    mode: str | None = None) -> dict:
    r"""`RecedingHorizonDriver` settings for the scenario road called ``name`` (None: a
    road from a file); ``friction`` the planner's friction of `scenario_driver`; ``mode``
    (None: the settings of the real-time iteration, the drivers' default, without a
    ``mode`` key) "rti" or "converged", returned as the settings' ``mode``. A converged
    driver takes a fresh Hessian every pass (``hessian_update`` "every"): keeping a sample's
    first Hessian is the economy of a fixed number of real-time passes, and a solve run to
    its tolerance with it converges linearly and mostly reaches its cap (on a road file's
    drive 332 of 386 solves, against 2 with a fresh one; docs/performance.md). It also plans
    a lost plan again from the cold start (`replan_kkt` `CONVERGED_REPLAN_KKT`, where the
    road's settings have none): a solve that fails at its cap leaves an iterate far from
    any plan, and shifted on, it made the next samples' solves fail in turn (on corner90 the
    residuals grew to $10^{27}$ and the car left the road; docs/driver.md, "A converged
    driver re-plans a lost plan").

    - The stage (12-17 m/s on a 4 m road): `FAST_ROAD_DRIVER`. At those speeds 4 passes per
      sample leave the plans far from converged, so a sample takes 10 passes that keep its
      first Hessian, and a plan lost on the way (KKT residual past 100, as braking into a
      corner can leave it) is planned again from the cold start in at most 20 passes; the
      planner uses 90 % of the believed peak, since the planning tire is not the plant's;
      the corridor margin is 0.3 m.
    - The benchmark corners (corner90, uturn, sturn; 2 m wide): `CORNER_DRIVER`. A car at
      the road's limit runs some tens of centimetres past its planned path, so the corridor
      margin is 0.4 m; it narrows in proportion to the planned grip below the planning
      car's (`margin_grip_power` 1: about 0.22 m on the icy patch), since an icy apex needs
      the road's width. The planning tire keeps its $B$ on every surface (no
      `stiffness_power`): a planning tire that kept its slip stiffness on less grip
      (`stiffness_power` 1) completed as many corner drives on the LuGre plant and lost
      half the 20 %-slippier ones on a Magic Formula plant (docs/driver.md).
    - A road from a file (None, or a name that is not a scenario road's):
      `FILE_ROAD_DRIVER`, for circuits driven at 35-47 m/s: 16 kept-Hessian passes, the
      stage's friction margin, a lost plan planned again (`replan_kkt` 100) in at most 40
      passes, a 0.5 m corridor margin, the terminal speed bound at 85 %
      (`terminal_backoff`), the axles' combined slip bounded by 0.10
      (`slip_limit`: the plant's tire peaks at 3-4 % slip at those speeds) and a soft
      corridor (`corridor_penalty`).

    Every road's settings have the traction control (`traction_limit`
    `DRIVER_TRACTION_LIMIT`): the plans' torques otherwise spin the plant's wheels up on the
    corners' exits. With ``friction`` = "estimate" on the benchmark corners the driver also
    brakes the front axle on the first `DRIVER_PROBE_DISTANCE` metres
    (`RecedingHorizonDriver.probe_distance`), so that the estimator knows the grip before
    the first corner; the stage's first corner teaches it soon enough. The test is not
    balanced by the rear axle driving (`probe_direction` 'balanced'): on the plant's own
    tire that completes as many drives, but on a plant with a Magic Formula tire the car
    then entered the corners of 20 % less grip faster than its grip allowed (docs/driver.md,
    "The test brake on a tire of another family").

    What each setting was measured against (drives completed over noise seeds, times
    against the oracle): docs/driver.md, and for the stage docs/drive.md ("Passes on the
    stage", "A 0.3 m margin on the stage")."""
    if name == "stage":
        settings = dict(FAST_ROAD_DRIVER)
    else:
        settings = dict(CORNER_DRIVER) if name in _CORNERS else dict(FILE_ROAD_DRIVER)
    if friction is not None:
        _check_name("friction", friction, ("estimate", "nominal", "oracle"))
    if friction == "estimate" and name in _CORNERS:
        settings["probe_distance"] = DRIVER_PROBE_DISTANCE
    if mode is not None:
        _check_name("mode", mode, ("rti", "converged"))
        settings["mode"] = mode
        if mode == "converged":
            settings["hessian_update"] = "every"
            settings.setdefault("replan_kkt", CONVERGED_REPLAN_KKT)
    return settings


ESTIMATORS = ("axle-grip", "axle-peak", "cautious")
"""The kinds of `driver_estimator`: `AxleGripEstimator` (the plant's tire family assumed),
the shape-free `AxlePeakEstimator`, and both (`CautiousGripEstimator`)."""

DRIVER_MIN_UTILISATION = 0.7
"""`AxleGripEstimator.min_utilisation` of `driver_estimator`."""

DRIVER_SLIDING_SLIP = 0.1
"""`AxleGripEstimator.sliding_slip` of `driver_estimator`."""


def driver_estimator(prior_peak: float = BENCHMARK_PEAK,
                     surface: AbstractGripField | None = None, kind: str = "axle-grip"
                     ) -> AbstractGripEstimator:
    r"""The grip estimator of the receding-horizon driver's scenarios: `AxleGripEstimator`
    with the prior of the road whose peak at 20 m/s is ``prior_peak`` (`scale_for_peak`)
    and `min_utilisation` = `DRIVER_MIN_UTILISATION` (0.7, the estimator's default 0.5)
    and `sliding_slip` = `DRIVER_SLIDING_SLIP` (0.1; the estimator's default: off).

    The driver accelerates out of the start at 1-2 % slip, where the LuGre curve is steep
    and the measured slip noisy and lagging the force; with half the peak as the gate those
    samples pull a correct prior low, hence 70 %. The price: a road much worse than believed
    is learnt only once an axle uses 70 % of the *believed* peak, which a road of less than
    70 % of it never gives; there the axles slide, and the samples where an axle's combined
    slip reaches 10 % count too. The measurements: docs/driver.md.

    ``surface``: the map of the road's relative grip (`AxleGripEstimator.surface`, e.g.
    `DriveScenario.surface_map`), relative to the surface the prior describes (the scenarios'
    maps: the road's best surface, so that the map only warns), as ratios of friction
    scales; the shape-free estimator gets it as ratios of peaks (`PeakRatios` at the
    prior's scale).

    ``kind``: "axle-grip" (the above), "axle-peak" (the shape-free `AxlePeakEstimator` with
    the prior peak ``prior_peak``: for a plant whose tire is not of the LuGre family; its
    driver plans with the estimated peak itself, `scenario_driver`) or "cautious" (both, in
    a `CautiousGripEstimator`; its driver plans with the smaller of their peaks)."""
    _check_name("kind", kind, ESTIMATORS)
    lam_prior = scale_for_peak(prior_peak)
    model = AxleGripEstimator(prior_scale=lam_prior,
                              min_utilisation=DRIVER_MIN_UTILISATION,
                              sliding_slip=DRIVER_SLIDING_SLIP, surface=surface)
    if kind == "axle-grip":
        return model
    shape_free = AxlePeakEstimator(prior_peak=prior_peak, surface=None if surface is None else
                                   PeakRatios(surface, peak_surface_factor(lam_prior),
                                              lam_prior))
    return shape_free if kind == "axle-peak" else CautiousGripEstimator(model, shape_free)


def scenario_driver(scenario: DriveScenario, friction: str = "estimate", *,
                    pace_notes: bool = False, estimator: str = "axle-grip", **settings
                    ) -> tuple[RecedingHorizonDriver, AbstractGripEstimator | None]:
    r"""``(driver, estimator)``: the `RecedingHorizonDriver` of ``scenario`` with the
    planner's ``friction`` ("estimate", "nominal" or "oracle"), paced to the plant's
    actuators (their `sample_time`, and their delay in whole samples: the driver predicts
    over one delay, the first channel's; the scenarios delay all three alike), and for
    "estimate" its estimator (`driver_estimator`; None otherwise).

    ``pace_notes``: the driver and the estimator share `DriveScenario.surface_map` (the
    driver's table carries it as its `scale` column, `RecedingHorizonDriver.surface_map`).
    ``settings``: further `RecedingHorizonDriver` fields, e.g. ``driver_settings(road)``
    (not applied here: a road from a file named like a scenario's is not that road).
    ``estimator``: the kind of `driver_estimator` ("axle-grip", "axle-peak" or "cautious";
    with "axle-peak" the driver plans with the estimated peak itself,
    `RecedingHorizonDriver.peak_model` "estimated", with "cautious" with the smaller of the
    two estimators' peaks, `peak_model` "cautious")."""
    _check_name("friction", friction, ("estimate", "nominal", "oracle"))
    _check_name("estimator", estimator, ESTIMATORS)
    if estimator != "axle-grip" and friction == "estimate":
        model = "estimated" if estimator == "axle-peak" else "cautious"
        settings = {"peak_model": model} | settings
    notes = scenario.surface_map() if pace_notes else None
    act = scenario.plant.actuators
    table = scenario.table if notes is None else scenario.table.with_grip(notes)
    driver = RecedingHorizonDriver(table=table, friction=friction,
                                   sample_time=act.sample_time,
                                   delay_samples=int(act.delay_samples()[0]),
                                   surface_map=notes is not None, **settings)
    if friction != "estimate":
        return driver, None
    return driver, driver_estimator(surface=notes, kind=estimator)


def plant_surface_factor(tire: AbstractTire | None) -> SurfaceFactor | None:
    """The `DrivePlant.surface_factor` that puts `tire` on the scenarios' surfaces: None
    (their scales themselves) for a LuGre tire or None (the default LuGre), the peaks'
    `peak_surface_factor` for a tire whose peak is proportional to its friction factors, a
    Magic Formula (params `MFParams`) or a `FrictionEllipseTire` (the planning car's, a
    plant that is the planner's model in its tire)."""
    if isinstance(getattr(tire, "params", None), MFParams) or isinstance(
            tire, FrictionEllipseTire):
        return peak_surface_factor(nominal_scale())
    return None


def nominal_scale() -> float:
    r"""$\lambda_0$: the plant tire's friction scale whose peak is the benchmark's
    $D = 0.52$ (`scale_for_peak`)."""
    return scale_for_peak(BENCHMARK_PEAK)


def scale_for_peak(peak: float) -> float:
    r"""The friction scale $\lambda$ with $\mu^*(\lambda)$ = `peak` (one number; `plant_peak`),
    by `scale_of_peak` (bisection on $\log\lambda \in [\log 10^{-3}, \log 10]$, where $\mu^*$
    increases, to rounding); a peak outside that range is refused."""
    return _scale_for_peak(_one_number("scale_for_peak", "peak", peak))


def _one_number(owner: str, name: str, value) -> float:
    """``value`` as a float, or a ``ValueError`` naming `name` when it is not one number."""
    if np.ndim(value) != 0:
        raise ValueError(f"{owner}: {name} must be one number, got shape {np.shape(value)}")
    try:
        return float(value)
    except (TypeError, ValueError):
        raise ValueError(f"{owner}: {name} must be one number, got {value!r}") from None


@functools.lru_cache(maxsize=64)
def _scale_for_peak(peak: float) -> float:
    lo, hi = 1e-3, 10.0
    if not (plant_peak(lo) < peak < plant_peak(hi)):
        raise ValueError(f"scale_for_peak: peak must lie in ({plant_peak(lo):.4g}, "
                         f"{plant_peak(hi):.4g}), got {peak:g}")
    est = AxleGripEstimator()
    return float(_scale(est.tire, jnp.asarray(peak), est.reference_speed))


@eqx.filter_jit
def _peak(estimator, scale):
    return estimator.peak(scale)


@eqx.filter_jit
def _scale(tire, peak, speed):
    return scale_of_peak(tire, peak, speed)


def plant_peak(scale: float) -> float:
    r"""$\mu^*(\lambda)$ of the plant's tire on a road of friction scale `scale` (one number;
    `AxleGripEstimator.peak`, whose assumed tire is the plant's)."""
    return _plant_peak(_one_number("plant_peak", "scale", scale))


@functools.lru_cache(maxsize=64)
def _plant_peak(scale: float) -> float:
    if not (math.isfinite(scale) and scale > 0):
        raise ValueError(f"plant_peak: scale must lie in (0, inf), got {scale:g}")
    return float(_peak(AxleGripEstimator(), jnp.asarray(float(scale))))


class ScenarioGrip(eqx.Module):
    r"""A grip scenario on a road: the plant's `field` ($\lambda(x, y)$), and the true peak
    friction along the centre line, `peak` $= \mu^*(\lambda(c(s)))$ at the arc lengths
    `arc_length` (uniform, at most 0.25 m apart); `name`."""

    name: str = eqx.field(static=True)
    field: AbstractGripField
    arc_length: Float[Array, " K"]
    peak: Float[Array, " K"]

    def peak_at(self, s):
        """The true peak friction at arc lengths `s` [m] (linear between the samples; JAX)."""
        return jnp.interp(s, self.arc_length, self.peak)


class PatchedProfile(AbstractGripField):
    r"""A `GripProfile` $\lambda_p$ with circular patches that multiply it: $\lambda =
    \lambda_p(x, y)\prod_i\bigl(1 + w_i(f_i - 1)\bigr)$, $w_i = \frac12\bigl(1 -
    \tanh\frac{|p - c_i| - R_i}{w}\bigr)$ as in `GripPatches` (a factor $f_i = 1$ is no
    patch). Every grip scenario is one of these with two stations and one patch, so that
    plants of different scenarios batch in one `vmap` and share a compilation.

    **Fields:** `profile` (`GripProfile`), `centres` [m] (N, 2), `radii` [m] (N,),
    `factors` $f_i$ (N,), `width` $w$ [m] (1).
    """

    profile: GripProfile
    centres: Float[Array, "N 2"] = array_field()
    radii: Float[Array, " N"] = array_field()
    factors: Float[Array, " N"] = array_field()
    width: Float[Array, ""] = array_field(default=1.0)

    def __check_init__(self):
        GripPatches(centres=self.centres, radii=self.radii, scales=self.factors,
                    width=self.width)  # the same checks, with the patches' names

    def scale_at(self, x, y):
        lam = self.profile.scale_at(x, y)
        for i in range(self.centres.shape[0]):
            d = safe_hypot(x - self.centres[i, 0], y - self.centres[i, 1])
            w = 0.5 * (1.0 - jnp.tanh((d - self.radii[i]) / self.width))
            lam = lam * (1.0 + w * (self.factors[i] - 1.0))
        return lam


def _is_scenario_road(road: CentrelineRoad) -> bool:
    """Whether `road` is the scenario road of its name (not only named like it: a road file
    called ``stage.csv`` is named ``stage``)."""
    if road.name not in _ROADS:
        return False
    own = scenario_road(road.name)
    ends = np.array([0.0, road.length])
    return (abs(road.length - own.length) <= 1e-9 * own.length
            and np.allclose(np.stack(road.position(ends)), np.stack(own.position(ends)),
                            rtol=0.0, atol=1e-6))


def _grip_field(name: str, road: CentrelineRoad) -> PatchedProfile:
    lam0 = nominal_scale()
    (x0, x1), (y0, y1) = road.position(np.array([0.0, road.length]))
    direction = math.atan2(float(y1 - y0), float(x1 - x0))
    xt, yt = road.position(road.length / 3.0)
    third = ((float(xt) - float(x0)) * math.cos(direction)
             + (float(yt) - float(y0)) * math.sin(direction))
    if name == "rising" and (road.closed or third <= 0.0):
        raise ValueError(
            f"grip 'rising' on road {road.name!r}: the grip rises along the line from the "
            "road's start to its end, up to the point a third of the road along it; "
            + ("a closed road has no such line" if road.closed else
               f"this road's third lies {third:.1f} m behind its start on that line")
            + ". Choose another grip (nominal, minus20, icy) or an open road that runs "
            "from its start towards its end")
    scenario = _is_scenario_road(road)
    s0, s1 = main_corner(road.name) if scenario else (0.0, road.length)
    cx, cy = road.position(0.5 * (s0 + s1))
    radius = _ROADS[road.name][5] if scenario else 3.0
    start = end = lam0
    factor = 1.0
    if name == "minus20":
        start = end = scale_for_peak(MINUS20_PEAK * BENCHMARK_PEAK)
    elif name == "icy":
        factor = scale_for_peak(PATCH_PEAK * BENCHMARK_PEAK) / lam0
    elif name == "rising":
        start = scale_for_peak(RISING_START * BENCHMARK_PEAK)
    profile = GripProfile(stations=jnp.asarray([0.0, third]), scales=jnp.asarray([start, end]),
                          origin=jnp.asarray([float(x0), float(y0)]), direction=direction)
    return PatchedProfile(profile=profile, centres=jnp.asarray([[float(cx), float(cy)]]),
                          radii=jnp.asarray([radius]), factors=jnp.asarray([factor]), width=1.0)


def scenario_grip(name: str, road: CentrelineRoad) -> ScenarioGrip:
    """The grip scenario `name` (`GRIP_NAMES`: nominal, minus20, icy, rising; module
    docstring) on `road` (a scenario road: the icy patch sits on its main corner), with the
    true peak friction along the centre line."""
    _check_name("grip", name, GRIP_NAMES)
    field = _grip_field(name, road)
    num = max(2, int(math.ceil(road.length / 0.25)) + 1)
    s = np.linspace(0.0, road.length, num)
    x, y = road.position(s)
    peak = _peaks_along(AxleGripEstimator(), field, jnp.asarray(x), jnp.asarray(y))
    return ScenarioGrip(name=name, field=field, arc_length=jnp.asarray(s), peak=peak)


@eqx.filter_jit
def _peaks_along(estimator, field, x, y):
    return jax.vmap(lambda xi, yi: estimator.peak(field.scale_at(xi, yi)))(x, y)


class DriveScenario(eqx.Module):
    r"""A drive to make: the `road` (`CentrelineRoad`, NumPy: keep it out of `jit`) and its
    `table` (`RoadTable`, JAX, its `scale` column the grip's friction scale), its
    `grip` (`ScenarioGrip`), the `plant` (`DrivePlant` on that grip), the initial plant
    state `state0` (on the start gate's centre, heading along the road, at `start_speed`
    [m/s], wheels rolling freely), and the time budget `num_samples` (control samples).
    `name` is ``road/grip``."""

    name: str = eqx.field(static=True)
    road: CentrelineRoad
    table: RoadTable
    grip: ScenarioGrip
    plant: DrivePlant
    state0: DriveState
    start_speed: float = eqx.field(static=True)
    num_samples: int = eqx.field(static=True)

    @property
    def road_name(self) -> str:
        return self.name.split("/")[0]

    def surface_map(self) -> RelativeGrip:
        """The map of the road's relative grip that a co-driver's pace notes would give:
        the plant's grip field relative to the best surface along the centre line, so that
        every ratio is at most 1 and the map is a list of warnings (where the road is worse,
        and by how much) that says nothing of the grip's level: uniform on the nominal and
        minus20 roads, the patch's ratio on the icy one, 0.55 rising to 1 on the rising one.
        The estimator's prior then describes the road's best surface, and the map lowers it
        where the notes warn."""
        x, y = self.road.position(np.asarray(self.grip.arc_length))
        scale = np.asarray(self.grip.field.scale_at(jnp.asarray(x), jnp.asarray(y)))
        return RelativeGrip(self.grip.field, float(np.max(scale)))

    @property
    def grip_name(self) -> str:
        return self.grip.name

    @property
    def sample_time(self) -> float:
        return float(self.plant.actuators.sample_time)

    def primitive_road(self) -> CentrelineRoad:
        """The road with its start gate fixed to the drive's start: the centre line
        ($n = 0$) at `start_speed`, for minimum-time drives that start where the car does."""
        return self.road.with_gates(Gate.at(self.road, 0.0, n_min=0.0, n_max=0.0,
                                            speed=self.start_speed), self.road.end)


def drive_scenario(road_name: str, grip_name: str = "nominal", *,
                   actuators: DriveActuators | None = None,
                   sensors: DriveSensors | None = None, start_speed: float | None = None,
                   time_budget: float | None = None, substeps: int = 40,
                   table_spacing: float = 0.1, table_points: int | None = None,
                   tire: AbstractTire | None = None) -> DriveScenario:
    r"""The scenario `road_name` x `grip_name` (`ROAD_NAMES` x `GRIP_NAMES`): plant with the
    default `DriveActuators` and `DriveSensors` unless given, on `tire` (default the
    `DrivePlant`'s lumped 2D LuGre; any tire `scale_friction` scales: a LuGre tire meets the
    grip's scales $\lambda$ themselves; a Magic Formula, given with its friction on the
    nominal road (`mf_plant_tire`), meets every surface with the peak the scenario states,
    through `peak_surface_factor`: a plant of another tire family than the drivers
    assume, on the same roads), `substeps` integration steps
    per sample, the start speed [m/s] (default `START_SPEEDS`) and the time budget [s]
    (default `TIME_BUDGETS`); the road table at `table_spacing` [m] with `table_points`
    samples (default just enough; more pad it, so that tables of different roads batch)."""
    _check_name("road", road_name, ROAD_NAMES)
    _check_name("grip", grip_name, GRIP_NAMES)
    road = scenario_road(road_name)
    grip = scenario_grip(grip_name, road)
    v0 = START_SPEEDS[road_name] if start_speed is None else float(start_speed)
    if not (math.isfinite(v0) and 0 < v0 <= MAX_START_SPEED):
        raise ValueError(f"drive_scenario: start_speed must lie in (0, {MAX_START_SPEED:g}] "
                         f"m/s, got {v0:g}")
    budget = TIME_BUDGETS[road_name] if time_budget is None else float(time_budget)
    if not (math.isfinite(budget) and 0 < budget <= MAX_TIME_BUDGET):
        raise ValueError(f"drive_scenario: time_budget must lie in (0, {MAX_TIME_BUDGET:g}] s,"
                         f" got {budget:g}")
    plant = DrivePlant(grip=grip.field, substeps=substeps,
                       actuators=DriveActuators() if actuators is None else actuators,
                       sensors=DriveSensors() if sensors is None else sensors,
                       **({} if tire is None else {"tire": tire}),
                       surface_factor=plant_surface_factor(tire))
    x0, y0 = road.position(0.0)
    state0 = init_drive(plant, vx=v0, x=float(x0), y=float(y0), psi=float(road.heading(0.0)))
    table = RoadTable.from_road(road, table_spacing, table_points)
    table = table.with_grip(grip.field)
    T = float(plant.actuators.sample_time)
    return DriveScenario(name=f"{road_name}/{grip_name}", road=road, table=table, grip=grip,
                         plant=plant,
                         state0=state0, start_speed=v0,
                         num_samples=int(math.ceil(budget / T - 1e-9)))
