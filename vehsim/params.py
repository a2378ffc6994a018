"""Every named preset in one place (sources in docs/parameters.md).

A preset is a published or documented parameter set, built by a function of no arguments;
`preset(name)` looks one up by name (the names the command line and result files use),
`PRESETS` lists them all and `PRESET_KINDS` says what each one is. The definitions stay
beside their models, each with its source in its docstring:

- ``tire_params``: the literature's tire parameter sets, `vehsim.tire.params` (also
  importable from here: ``from vehsim.params import table3``);
- ``tire``: the benchmark maneuvers' tire (`vehsim.tire.friction_ellipse`) and the LuGre tire
  matched to it for the replays (`vehsim.optimal.replay`);
- ``vehicle_params``: the benchmark maneuvers' half-car (`vehsim.vehicle.params`);
- ``surface``: the named road surfaces of the braking studies (`vehsim.control.road.surfaces`);
- ``brake_hardware``: the braking hardware with every effect on or off
  (`vehsim.control.plant.hardware`);
- ``robot_plant``: the Khepera plant with every effect on or off (`vehsim.robot.khepera`);
- ``robot_mission``: the missions of report Table 2 (`vehsim.robot.missions`).
"""

from __future__ import annotations

import functools
from collections.abc import Callable
from typing import Any

from .control.plant.hardware import ideal_hardware, realistic_hardware
from .control.road.surfaces import SURFACES, surface
from .optimal.replay import matched_lugre_tire
from .robot.khepera import ideal_plant, realistic_plant
from .robot.missions import EASY, LONG_DISTANCE, NORMAL, SINGULAR
from .tire.friction_ellipse import rally_gravel_tire
from .tire.params import (
    bakker1987 as bakker1987,
    cdc1999 as cdc1999,
    lugre2d_bakker1987 as lugre2d_bakker1987,
    lugre2d_bakker1987_mz as lugre2d_bakker1987_mz,
    table3 as table3,
)
from .vehicle.params import rally_gravel


_TABLE: tuple[tuple[str, str, Callable[[], Any]], ...] = (
    ("table3", "tire_params", table3),
    ("cdc1999", "tire_params", cdc1999),
    ("bakker1987", "tire_params", bakker1987),
    ("lugre2d_bakker1987", "tire_params", lugre2d_bakker1987),
    ("lugre2d_bakker1987_mz", "tire_params", lugre2d_bakker1987_mz),
    # the benchmark maneuvers' tire and vehicle (docs/maneuvers.md), and the LuGre tire
    # matched to that tire for the replays
    ("rally_gravel_tire", "tire", rally_gravel_tire),
    ("matched_lugre_tire", "tire", matched_lugre_tire),
    ("rally_gravel", "vehicle_params", rally_gravel),
    # closing the loop (report section 2.2): road surfaces and braking hardware
    *((name, "surface", functools.partial(surface, name)) for name in SURFACES),
    ("realistic_hardware", "brake_hardware", realistic_hardware),
    ("ideal_hardware", "brake_hardware", ideal_hardware),
    # the Khepera robot and the missions of Table 2 (report section 2.1); a mission is an
    # immutable module, returned as it is
    ("realistic_plant", "robot_plant", realistic_plant),
    ("ideal_plant", "robot_plant", ideal_plant),
    ("mission_easy", "robot_mission", lambda: EASY),
    ("mission_normal", "robot_mission", lambda: NORMAL),
    ("mission_singular", "robot_mission", lambda: SINGULAR),
    ("mission_long_distance", "robot_mission", lambda: LONG_DISTANCE),
)

PRESETS: dict[str, Callable[[], Any]] = {name: build for name, _, build in _TABLE}
"""Every named preset: name -> a function of no arguments that builds it (sources:
docs/parameters.md)."""

PRESET_KINDS: dict[str, str] = {name: kind for name, kind, _ in _TABLE}
"""What each preset of `PRESETS` is: ``tire_params`` (`LuGreParams`, `LuGre2DParams`,
`MagicFormula1987Params`; ``lugre2d_bakker1987_mz`` with its load shape), ``tire`` (a tire
model), ``vehicle_params`` (`HalfCarParams`), ``surface`` (`Surface`), ``brake_hardware``
(`BrakeHardware`), ``robot_plant`` (`KheperaPlant`) or ``robot_mission`` (`Mission`)."""


def preset(name: str):
    """The preset called ``name`` (see `PRESETS`; what it is: `PRESET_KINDS`)."""
    try:
        return PRESETS[name]()
    except KeyError:
        raise ValueError(f"unknown preset {name!r}; known: {sorted(PRESETS)}") from None
