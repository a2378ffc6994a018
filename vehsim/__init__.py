"""vehsim: a differentiable vehicle simulator in JAX (after Tsiotras, 2004).

The public API is flat: everything a user needs is importable from ``vehsim``.
"""

from . import params as params
from .params import PRESETS as PRESETS, preset as preset
from .tire.distributed import DistributedLuGre as DistributedLuGre
from .tire.load import (
    AbstractLoadDistribution as AbstractLoadDistribution,
    PolynomialLoad as PolynomialLoad,
    QuarticLoad as QuarticLoad,
    TabulatedLoad as TabulatedLoad,
    TrapezoidalLoad as TrapezoidalLoad,
    UniformLoad as UniformLoad,
)
from .tire.lugre import (
    AbstractLongitudinalTire as AbstractLongitudinalTire,
    LuGreParams as LuGreParams,
    LumpedLuGre as LumpedLuGre,
    PointLuGre as PointLuGre,
    decay_rate as decay_rate,
    relative_velocity as relative_velocity,
    stribeck as stribeck,
)
from .tire.steady_state import (
    braking_mu_uniform as braking_mu_uniform,
    driving_mu_uniform as driving_mu_uniform,
    steady_state_mu as steady_state_mu,
    z_ss as z_ss,
)
from .tire.transient import TireSolution as TireSolution, simulate_tire as simulate_tire


# isort: split
# issue 5: vehicles, simulate, sweeps
from .tire.friction_ellipse import (
    FrictionEllipseTire as FrictionEllipseTire,
    rally_gravel_tire as rally_gravel_tire,
)
from .tire.linear import LinearTire as LinearTire
from .vehicle.base import AbstractVehicle as AbstractVehicle
from .vehicle.params import HalfCarParams as HalfCarParams, rally_gravel as rally_gravel
from .vehicle.reduced import ReducedHalfCar as ReducedHalfCar


# isort: split
# issue 7: optimal driving primitives
from .optimal.nlp import (
    AbstractStagewiseNLP as AbstractStagewiseNLP,
    interior_point as interior_point,
    IPOptions as IPOptions,
    IPSolution as IPSolution,
)
from .optimal.primitives import (
    max_exit_primitive as max_exit_primitive,
    min_time_primitive as min_time_primitive,
    point_mass_bound as point_mass_bound,
    Primitive as Primitive,
)
from .optimal.roads import Road as Road, road as road


__version__ = "0.1.0"
