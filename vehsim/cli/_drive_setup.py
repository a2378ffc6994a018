"""What `vehsim drive` drives: the road, the plant on its grip, the controller and the
estimator its options name, the drive and its measurements."""

from __future__ import annotations

import dataclasses
import math


@dataclasses.dataclass
class Scenario:
    """A drive to run: `plant` (`DrivePlant`), `controller`, `estimator` (None: none),
    `state0` (`DriveState`), `num_samples`, the nominal road's grip scale `nominal_scale`
    and peak friction `nominal_D`, and the tire's peak friction at scale 1,
    `nominal_peak`."""

    road: object
    plant: object
    controller: object
    estimator: object
    state0: object
    num_samples: int
    nominal_scale: float
    nominal_D: float
    nominal_peak: float

    def m0(self, seed: int):
        """The measurement before the first sample (as `simulate_drive` draws it)."""
        import jax

        from ..drive.plant import measure_drive

        return measure_drive(self.plant, self.state0, jax.random.fold_in(
            jax.random.key(seed), 0))


def road(args):
    """The road of ``--road`` or ``--road-file`` (read and checked before anything compiles)."""
    if args.road_file is not None:
        from .._road_files import read_road

        return read_road(args.road_file, closed=args.closed)
    from ..optimal.centreline import CentrelineRoad

    # stand-in shapes until the scenario roads exist
    segments = {"corner90": [("straight", 20.0), ("arc", 8.0, 90.0), ("straight", 20.0)],
                "uturn": [("straight", 20.0), ("arc", 8.0, 180.0), ("straight", 20.0)],
                "sturn": [("straight", 15.0), ("arc", 10.0, 60.0), ("arc", 10.0, -60.0),
                          ("straight", 15.0)],
                "stage": [("straight", 30.0), ("arc", 30.0, 60.0), ("straight", 20.0),
                          ("arc", 15.0, -90.0), ("straight", 30.0)]}[args.road]
    return CentrelineRoad.from_segments(segments, 4.0, name=args.road)


def grip_field(args, road, nominal_scale: float):
    """`UniformGrip` at ``--grip`` times the nominal scale, or `GripPatches` on it."""
    import jax.numpy as jnp

    from ..drive.grip import GripPatches, UniformGrip

    base = args.grip * nominal_scale
    if not args.patch:
        return UniformGrip(scale=base)
    p = jnp.asarray(args.patch, dtype=float)
    return GripPatches(centres=p[:, :2], radii=p[:, 2], scales=p[:, 3] * nominal_scale,
                       base=base)


def scenario(args, road) -> Scenario:
    import jax.numpy as jnp

    from ..drive.estimator import AxleGripEstimator
    from ..drive.plant import DrivePlant, init_drive
    from ..drive.sensors import DriveSensors
    from ..drive.simulate import PathFollower

    nominal_D = 0.52
    nominal_peak = float(AxleGripEstimator().peak(1.0))
    nominal_scale = nominal_D / nominal_peak
    plant = DrivePlant(grip=grip_field(args, road, nominal_scale),
                       sensors=DriveSensors(noise_on=args.noise))
    x0, y0 = (float(v) for v in road.position(0.0))
    psi0 = float(road.heading(0.0))
    state0 = init_drive(plant, vx=8.0, x=x0, y=y0, psi=psi0)
    duration = args.duration if args.duration is not None else max(5.0, road.length / 6.0)
    num = int(math.ceil(duration / 0.05 - 1e-9))
    controller = PathFollower(curvature=0.0, torque=jnp.array([0.0, 100.0]))
    estimator = AxleGripEstimator(prior_scale=nominal_scale) if args.controller == "rh" \
        else None
    return Scenario(road, plant, controller, estimator, state0, num, nominal_scale, nominal_D,
                    nominal_peak)


def simulate(sc: Scenario, seed: int):
    import jax

    from ..drive.simulate import simulate_drive

    @jax.jit
    def run(key):
        return simulate_drive(sc.plant, sc.controller, sc.state0, key, sc.num_samples,
                              estimator=sc.estimator)

    return run(jax.random.key(seed))


def metrics(sc: Scenario, run) -> dict:
    """``drive_time`` [s] (the centre of gravity crossing the end, interpolated; None if it
    did not), ``max_distance_off_road`` [m] and ``completed`` (crossed within 5 cm)."""
    import numpy as np

    car = np.asarray(run.states.car)
    t = np.asarray(run.states.t)
    s, _ = sc.road.to_frenet(car[:, 0], car[:, 1])
    off = float(np.max(sc.road.distance_off_road(car[:, 0], car[:, 1])))
    end = sc.road.length - 1e-6
    crossed = np.nonzero(s >= end)[0]
    drive_time = None
    if crossed.size and crossed[0] > 0:
        k = crossed[0]
        drive_time = float(np.interp(end, [s[k - 1], s[k]], [t[k - 1], t[k]]))
    return {"drive_time": drive_time, "max_distance_off_road": off,
            "completed": drive_time is not None and off <= 0.05}
