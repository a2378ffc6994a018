r"""Braking scenarios by name: a named surface (and a change to another), a controller by
name, and the observer that knows the tire but not the road.

The observer's model is the tire of the first surface at the family's prior $\theta$
(`Surface.prior_theta`), projected onto the family's range: it is told the tire, not the
road, and after a change it keeps the first surface's tire (the road families share their
tire, except cobblestone's $\sigma_0$).
"""

from __future__ import annotations

import math

import jax.numpy as jnp

from ...tire.lugre import AbstractLongitudinalTire
from ..controllers.braking import (
    AbstractBrakeController,
    LockedWheel,
    PeakSlipTracking,
    RuleBasedABS,
    SlipTracking,
)
from ..controllers.peak_seeking import PeakSeekingABS
from ..estimation.observer import FrictionObserver
from ..plant.quarter_car import BrakingScenario, SurfaceChange, braking_quarter_car
from ..road.surfaces import Surface, surface


CONTROLLERS = {"locked": LockedWheel, "rule": RuleBasedABS, "fixed": SlipTracking,
               "estimate": PeakSlipTracking, "seek": PeakSeekingABS}
"""Controllers by the names the command line and result files use."""


def controller(name: str) -> AbstractBrakeController:
    """The controller called `name` (a key of `CONTROLLERS`) with its default settings."""
    if name not in CONTROLLERS:
        raise ValueError(f"unknown controller {name!r}; known: {', '.join(CONTROLLERS)}")
    return CONTROLLERS[name]()


def observer_for(srf: Surface, **changes) -> FrictionObserver:
    """The observer of the tire of `srf`, started at its family's prior road condition."""
    lo, hi = srf.theta_range
    return FrictionObserver(srf.with_theta(srf.prior_theta), theta_min=lo, theta_max=hi,
                            **changes)


def braking_scenario(name: str, speed: float = 30.0, change_to: str | None = None,
                     change_distance: float = math.inf, change_time: float = math.inf,
                     tire: AbstractLongitudinalTire | None = None):
    """``(BrakingScenario, FrictionObserver)`` of a braking from `speed` [m/s] on the surface
    `name`, changing to the surface `change_to` at `change_distance` [m] or `change_time` [s]
    (`tire`: a plant tire other than the surface's, e.g. `other_tire(name)`, with the
    observer still built for the surface)."""
    if change_to is None and not (math.isinf(change_distance) and math.isinf(change_time)):
        raise ValueError("braking_scenario: change_distance and change_time place a change "
                         "of surface: give the surface with change_to")
    first = surface(name)
    plant_tire = first.tire() if tire is None else tire
    change = None
    if change_to is not None:
        change = SurfaceChange(surface(change_to).tire(), distance=change_distance,
                               time=change_time)
    scenario = BrakingScenario(braking_quarter_car(plant_tire), speed, change)
    return scenario, observer_for(first)


def true_theta(scenario: BrakingScenario, ts, x):
    r"""The true $\theta$ along a run (samples `ts`, distances `x`), where the tires are LuGre."""
    tire0, tire1 = scenario.car.tire, scenario.change.tire
    changed = (jnp.asarray(x) >= scenario.change.distance) | (
        jnp.asarray(ts) >= scenario.change.time)
    return jnp.where(changed, tire1.params.theta, tire0.params.theta)

