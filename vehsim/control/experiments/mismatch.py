r"""The tire-mismatch table: every controller on every tire, against the limits.

Rows are plant tires: the named surfaces (their own lumped LuGre) and tires of other shapes
(`other_tire`), each braked from `speed` with the observer built for a LuGre road
(`braking_scenario`) or any one estimator (e.g. the shape-free `PeakEstimator`); columns
are controllers. For each cell the stopping distance $d$ over the physical limit $d^*$
(`physical_limit`) and over the limit on the hardware $d^*_h$ (`actuated_limit`). Rows of
one tire structure (the named surfaces; the two Magic Formulas) and horizon share one
`simulate_braking_grid` call; a tire of another structure needs its own (the grid stacks
its scenarios).
"""

from __future__ import annotations

import math

import jax
import numpy as np

from ..controllers.braking import AbstractBrakeController
from ..estimation.base import AbstractFrictionEstimator
from ..loop import simulate_braking_grid, stack
from ..plant.hardware import BrakeHardware
from ..road.bound import actuated_limit, physical_limit
from .experiment import MAX_DURATION
from .scenarios import braking_scenario


def _horizon(limit_time: float) -> float:
    """The run's length for a limit's stopping time: 1.5 times it plus 1 s, rounded up to a
    power of two seconds (rows of like length share a grid), at most `MAX_DURATION`."""
    return min(2.0 ** math.ceil(math.log2(1.5 * limit_time + 1.0)), MAX_DURATION)


def mismatch_table(rows, controllers: dict[str, AbstractBrakeController],
                   hardware: BrakeHardware, speed: float = 30.0,
                   duration: float | None = None, key=0,
                   estimator: AbstractFrictionEstimator | None = None) -> dict:
    """Brake every row with every controller.

    **Arguments:** `rows`, ``{label: (surface, tire, change_to, change_distance)}``: the
    surface the observer is built for, the plant tire (`None`: the surface's own), and a
    surface change (`None`, `inf`: none); `controllers` by name; `hardware`; `speed` [m/s];
    `duration` [s] (default: per row, 1.5 times its limit's stopping time plus 1 s,
    rounded up to a power of two); `key` (the noise seed); `estimator` (default: each row's
    observer built for its surface; else this estimator in every row, e.g. the shape-free
    `PeakEstimator`).

    **Returns:** a dict of the `rows` and `controllers` (lists of labels) and arrays:
    ``distance`` (rows x controllers) [m], ``physical_limit`` and ``actuated_limit`` (rows)
    [m], ``over_physical`` and ``over_actuated`` (rows x controllers).
    """
    labels, names = list(rows), list(controllers)
    pairs = {label: braking_scenario(surface, speed, change_to, change_distance, tire=tire)
             for label, (surface, tire, change_to, change_distance) in rows.items()}
    if estimator is not None:
        pairs = {label: (sc, estimator) for label, (sc, _) in pairs.items()}
    limits = {label: [float(x) for x in physical_limit(pairs[label][0])] for label in labels}
    groups: dict = {}
    for label in labels:  # one grid per structure and horizon
        length = duration if duration is not None else _horizon(limits[label][1])
        groups.setdefault((jax.tree_util.tree_structure(pairs[label]), length), []).append(label)
    distance = np.full((len(labels), len(names)), math.nan)
    phys = np.array([limits[label][0] for label in labels])
    act = np.array([float(actuated_limit(pairs[label][0], hardware)[0]) for label in labels])
    for (_, length), members in groups.items():
        runs = simulate_braking_grid(stack([pairs[label][0] for label in members]),
                                     [controllers[n] for n in names],
                                     stack([pairs[label][1] for label in members]),
                                     jax.random.split(jax.random.PRNGKey(key), len(members)),
                                     hardware, duration=length)
        for j, label in enumerate(members):
            distance[labels.index(label)] = np.asarray(runs.stopping_distance[:, j])
    return {"rows": labels, "controllers": names, "distance": distance,
            "physical_limit": phys, "actuated_limit": act,
            "over_physical": distance / phys[:, None], "over_actuated": distance / act[:, None]}
