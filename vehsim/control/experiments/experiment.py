r"""One braking by name, judged: the controller and a locked wheel beside it, their distances
against the physical limit and the estimate of $\theta$ against the truth.

What `vehsim brake`, the reproduce section and the notebook run. The horizon is long enough
for the slowest of the two to stop (1.5 times the limit's stopping time, plus 1 s); both
runs are one jitted call (`simulate_braking_grid`).
"""

from __future__ import annotations

import math

import jax
import numpy as np
from jaxtyping import PRNGKeyArray

from ..._results import result_record
from ...tire.lugre import AbstractLongitudinalTire
from ..controllers.braking import LockedWheel
from ..loop import HANDBACK_SPEED, simulate_braking_grid, stack
from ..plant.hardware import BrakeHardware, realistic_hardware
from ..road.bound import physical_limit
from .metrics import available_friction, braking_record, estimate_record
from .scenarios import braking_scenario, controller, true_theta


MAX_DURATION = 150.0
"""The longest braking simulated [s] (a locked wheel on ice from 30 m/s takes about 90 s)."""


def _signals_of(runs, i, scenario, lugre_road):
    s = {k: np.asarray(v[i, 0]) for k, v in runs.signals.items()}
    s["peak_slip"], s["peak_mu"] = available_friction(scenario, s)
    s["theta_true"] = (np.asarray(true_theta(scenario, s["ts"], s["x"])) if lugre_road
                       else np.full_like(s["ts"], np.nan))
    return s


def braking_experiment(surface: str, controller_name: str = "estimate", speed: float = 30.0,
                       change_to: str | None = None, change_distance: float = math.inf,
                       change_time: float = math.inf, hardware: BrakeHardware | None = None,
                       key: PRNGKeyArray | None = None, duration: float | None = None,
                       tire: AbstractLongitudinalTire | None = None):
    """Brake on `surface` (changing to `change_to` at `change_distance` [m] or `change_time`
    [s]) from `speed` [m/s] with the controller `controller_name` and with a locked wheel;
    `tire`: a plant tire other than the surface's (e.g. `other_tire`), the observer still
    built for the surface, as `braking_scenario` (the truth of theta is then undefined:
    ``theta_true``, ``theta_settling_time_s`` and ``theta_bias`` are NaN).

    **Returns:** ``(record, signals)``: the JSON-ready record (the controller's
    ``stopping_distance_m``, ``bound_distance_m``, ``distance_over_bound``, the same over
    the limit on this hardware (``actuated_bound_distance_m``,
    ``distance_over_actuated_bound``), times, the
    estimate of theta, ``status`` and ``message``, and the same distances under
    ``locked_wheel``), and the saved signals of both runs by label, with the peak slip and
    friction of the true surface and the true theta at each sample.
    """
    hardware = realistic_hardware() if hardware is None else hardware
    key = jax.random.PRNGKey(0) if key is None else key
    scenario, observer = braking_scenario(surface, speed, change_to, change_distance,
                                          change_time, tire)
    lugre_road = tire is None
    if duration is None:
        duration = min(1.5 * float(physical_limit(scenario)[1]) + 1.0, MAX_DURATION)
    runs = simulate_braking_grid(stack([scenario]), [controller(controller_name), LockedWheel()],
                                 stack([observer]), key[None], hardware, duration=duration,
                                 save=True)
    out = {}
    for i, label in enumerate((controller_name, "locked")):
        run = jax.tree_util.tree_map(lambda a: a[i, 0], runs)
        out[label] = dict(braking_record(run, scenario, hardware), **result_record(run.result))
    signals = {label: _signals_of(runs, i, scenario, lugre_road)
               for i, label in enumerate((controller_name, "locked"))}
    s = signals[controller_name]
    below = np.nonzero(s["v"] < HANDBACK_SPEED)[0]
    t_end = float(s["ts"][below[0]]) if below.size else float(s["ts"][-1])
    record = {"surface": surface, "change_to": change_to, "change_distance_m": change_distance,
              "change_time_s": change_time, "controller": controller_name,
              "speed_m_s": speed, "duration_s": duration, **out[controller_name],
              "theta_true": float(scenario.car.tire.params.theta) if lugre_road else math.nan,
              **estimate_record(s["ts"], s["theta_hat"], s["theta_true"], 0.0, t_end),
              "locked_wheel": out["locked"]}
    return record, signals
