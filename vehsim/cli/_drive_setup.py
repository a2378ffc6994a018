"""What `vehsim drive` drives: the scenario its options name (road, grip, plant, start), the
controller and estimator, the drive itself and its outcome.

The grip options are peaks relative to the nominal road's: ``--grip 0.8`` is a road whose
peak friction is 0.8 x 0.52 (`vehsim.drive.scenarios.scale_for_peak` gives its scale,
since the tire's peak is not proportional to the friction scale), as the ``minus20``
scenario; ``--patch X,Y,R,0.5`` a patch of peak 0.26, as the ``icy`` one. So they are on a
plant of another tire family (``--plant-tire FILE.tir``): its Magic Formula has these peaks
on every surface (`vehsim.drive.plant_tires`).
"""

from __future__ import annotations

import math
from pathlib import Path


START_SPEED = 8.0
"""Start speed [m/s] of a road read from a file."""
PLAN_STAGE_LENGTH = 2.0
"""Stage length [m] of the nominal plan the tracking and open-loop drivers follow (at least
40 stages)."""


def road(args):
    """The road of ``--road`` or ``--road-file`` (read and checked before anything compiles)."""
    if args.road_file is not None:
        from .._road_files import read_road
        from ._options import input_file

        return read_road(input_file("--road-file", args.road_file),
                         closed=True if args.closed else None)  # else as the file says
    from ..drive.scenarios import scenario_road

    return scenario_road(args.road)


def _field(args, road):
    """The plant's grip field: the named conditions, or ``--grip`` with ``--patch``es."""
    import jax.numpy as jnp

    from ..drive.grip import GripPatches, UniformGrip
    from ..drive.scenarios import BENCHMARK_PEAK, scale_for_peak, scenario_grip

    if args.conditions is not None:
        return scenario_grip(args.conditions, road).field
    base = scale_for_peak(args.grip * BENCHMARK_PEAK)
    if not args.patch:
        return UniformGrip(scale=base)
    p = [list(v) for v in args.patch]
    return GripPatches(centres=jnp.asarray([v[:2] for v in p]),
                       radii=jnp.asarray([v[2] for v in p]),
                       scales=jnp.asarray([scale_for_peak(v[3] * BENCHMARK_PEAK) for v in p]),
                       base=base, width=1.0)


MAX_DURATION = 600.0
"""The longest drive [s]: ``--duration``'s upper limit, and the cap of a road file's default."""


def plant_tire(args):
    """The plant's tire of ``--plant-tire``: None for lugre (the `DrivePlant`'s default), or
    the Magic Formula of a .tir file (a path, or a shipped file's name) made the nominal
    road's peak (`mf_plant_tire`), which the scenario's plant puts on every surface by its
    peak (`plant_surface_factor`). The file is read and checked here, before anything
    compiles."""
    if args.plant_tire == "lugre":
        return None
    from ..drive.plant_tires import mf_plant_tire
    from ..drive.scenarios import BENCHMARK_PEAK
    from ..tire.mf6 import MFParams
    from ..tire.tir import read_tir, shipped_tires
    from ._options import input_file

    shipped = shipped_tires()
    path = shipped.get(args.plant_tire)
    if path is None:
        if not Path(args.plant_tire).exists():
            raise ValueError(f"--plant-tire: no such file {args.plant_tire!r}; give lugre, a "
                             ".tir file's path or a shipped tire: " + ", ".join(shipped))
        path = input_file("--plant-tire", args.plant_tire)
        if path.suffix.lower() != ".tir":
            raise ValueError(f"--plant-tire: {str(path)!r} is not a tyre property file; give "
                             "lugre, a .tir file or one of " + ", ".join(shipped))
    try:
        return mf_plant_tire(MFParams.from_tir(read_tir(path)), BENCHMARK_PEAK)
    except ValueError as e:  # a malformed file (TirError names its line), or no peak
        raise ValueError(f"--plant-tire {args.plant_tire}: {e}") from None


def scenario(args, road):
    """The `DriveScenario` of the options: the road and its table (the scale column the true
    friction scale), its grip (with the true peak along the centre line), the plant (sensors
    noisy or not), the start (the scenario's speed; a road file's at `START_SPEED`) and the
    time budget (``--duration``, default the scenario's, or a road file's length at 5 m/s
    plus 5 s, at most `MAX_DURATION`, the option's own limit)."""
    import jax
    import jax.numpy as jnp
    import numpy as np

    from ..drive.estimator import AxleGripEstimator
    from ..drive.horizon import RoadTable
    from ..drive.plant import DrivePlant, init_drive
    from ..drive.scenarios import (
        START_SPEEDS,
        TIME_BUDGETS,
        DriveScenario,
        ScenarioGrip,
        plant_surface_factor,
    )
    from ..drive.sensors import DriveSensors

    tire = plant_tire(args)
    field = _field(args, road)
    num = max(2, int(math.ceil(road.length / 0.25)) + 1)
    s = np.linspace(0.0, road.length, num)
    x, y = road.position(s)
    est = AxleGripEstimator()
    peak = jax.jit(jax.vmap(lambda xi, yi: est.peak(field.scale_at(xi, yi))))(
        jnp.asarray(x), jnp.asarray(y))
    name = args.conditions or "custom"
    grip = ScenarioGrip(name=name, field=field, arc_length=jnp.asarray(s), peak=peak)
    plant = DrivePlant(grip=field, sensors=DriveSensors(noise_on=args.noise),
                       **({} if tire is None else {"tire": tire}),
                       surface_factor=plant_surface_factor(tire))
    v0 = START_SPEEDS.get(args.road, START_SPEED) if args.road else START_SPEED
    budget = args.duration
    if budget is None:
        budget = TIME_BUDGETS[args.road] if args.road else min(road.length / 5.0 + 5.0,
                                                                 MAX_DURATION)
    x0, y0 = road.position(0.0)
    state0 = init_drive(plant, vx=v0, x=float(x0), y=float(y0), psi=float(road.heading(0.0)))
    table = RoadTable.from_road(road)
    table = table.with_grip(grip.field)
    T = float(plant.actuators.sample_time)
    return DriveScenario(name=f"{road.name}/{name}", road=road, table=table, grip=grip,
                         plant=plant, state0=state0, start_speed=v0,
                         num_samples=int(math.ceil(budget / T - 1e-9)))


def controller(args, sc):
    """``(controller, estimator)`` of ``--controller`` (and ``--mode``) on the scenario `sc`:
    the receding-horizon driver with the estimate (`driver_estimator`: the nominal road as
    its prior; with ``--pace-notes`` the map of the relative grip, `surface_map`, for both),
    the nominal friction or the true grip along the horizon (the oracle, as far ahead as
    ``--preview``), with ``--passes`` and ``--keep-hessian`` over the road's settings; or
    the nominal minimum-time drive (`nominal_primitive`) tracked or replayed, its solve's
    outcome kept as ``args.nominal_plan`` (`plan_record`; None for the other controllers)."""
    from ..drive.scenarios import driver_settings, scenario_driver

    act = sc.plant.actuators
    if args.controller in ("tracking", "open-loop"):
        from ..drive.baselines import (
            PrimitiveTracker,
            command_lead,
            nominal_primitive,
            open_loop_schedule,
            primitive_reference,
        )

        stages = max(40, int(round(sc.road.length / PLAN_STAGE_LENGTH)))
        prim = nominal_primitive(sc, num_stages=stages)
        args.nominal_plan = plan_record(prim)
        ref = primitive_reference(prim)
        if args.controller == "open-loop":
            return open_loop_schedule(ref, act, sc.num_samples), None
        return PrimitiveTracker(reference=ref, lead=command_lead(act)), None
    args.nominal_plan = None
    friction = {"rh": "estimate", "rh-nominal": "nominal", "rh-oracle": "oracle"}[
        args.controller]
    settings = driver_settings(None if args.road_file else args.road, friction,
                               mode=args.mode or "rti")
    if args.preview is not None:
        settings["preview"] = args.preview
    if args.passes is not None:
        settings["iterations"] = args.passes
    if args.keep_hessian is not None:
        settings["hessian_update"] = "first" if args.keep_hessian else "every"
    return scenario_driver(sc, friction, pace_notes=args.pace_notes,
                           estimator=args.estimator or "axle-grip", **settings)


def plan_record(prim) -> dict:
    """How a baseline's nominal plan was solved: its status and message (`RESULTS`), the
    interior point's iterations and the plan's time [s]."""
    from .._results import result_record

    sol = prim.solution
    return {**result_record(sol.result), "iterations": int(sol.iterations),
            "t_f": float(prim.t_f)}


def simulate(sc, driver, estimator, seed: int):
    """The drive in one compiled scan (`simulate_drive`), with the poses at every integration
    step: the experiments' drives (`vehsim drive` runs `drive.timed_drive`, which times the
    controller's samples)."""
    import jax

    from ..drive.simulate import simulate_drive

    @jax.jit
    def run(key):
        return simulate_drive(sc.plant, driver, sc.state0, key, sc.num_samples,
                              estimator=estimator, substep_poses=True)

    return run(jax.random.key(seed))


def outcome(sc, run) -> dict:
    """``drive_time`` [s] (None: never crossed the end gate), ``max_distance_off_road`` [m]
    and ``completed`` (`drive_outcome` on the path at every integration step)."""
    from ..drive.metrics import drive_outcome, drive_path

    t, x, y = drive_path(run, sc.state0)
    out = drive_outcome(sc.road, t, x, y)
    return {"drive_time": out.time, "max_distance_off_road": out.max_off_road,
            "completed": out.completed}
