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

# issue 4: braking data, quarter car, identification (report section 2.2)
from .identify.braking import (
    BrakingData as BrakingData,
    load_braking as load_braking,
    save_braking as save_braking,
    shipped_brakings as shipped_brakings,
)
from .identify.fit import (
    FitError as FitError,
    FitResult as FitResult,
    fit_closed_loop as fit_closed_loop,
    fit_open_loop as fit_open_loop,
    predict_closed_loop as predict_closed_loop,
    predict_open_loop as predict_open_loop,
)
from .vehicle.quarter_car import (
    ConstantLoad as ConstantLoad,
    LoadRelaxation as LoadRelaxation,
    MagicFormulaParams as MagicFormulaParams,
    PrescribedLoad as PrescribedLoad,
    QuarterCar as QuarterCar,
    RelaxedMagicFormula as RelaxedMagicFormula,
    simulate_quarter_car as simulate_quarter_car,
)


__version__ = "0.1.0"
