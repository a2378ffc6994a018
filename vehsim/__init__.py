"""vehsim: a differentiable vehicle simulator in JAX (after Tsiotras, 2004).

The public API is flat: everything a user needs is importable from ``vehsim``, each object
under the one name it has in its own (private or sub-package) module, re-exported here as
diffrax, equinox and optimistix do.

Importing vehsim applies one process-wide setting, before JAX starts its CPU backend: on
jaxlib 0.10 only, XLA's concurrency-optimised CPU scheduler is switched off in
``XLA_FLAGS`` (`configure_xla_cpu`, which says why and how to opt out). Importing vehsim
starts no JAX backend and makes no arrays: configure JAX (devices, float64) after it as you
like, before the first computation.
"""

from importlib.metadata import PackageNotFoundError as _PackageNotFoundError, version as _version

from ._xla_cpu import (
    configure_xla_cpu as configure_xla_cpu,
    refuse_unreadable_environment as _refuse_unreadable_environment,
)


_refuse_unreadable_environment()  # a JAX setting JAX's own import would refuse, named
configure_xla_cpu()  # before JAX starts its CPU backend; see its docstring for the scope

from . import params as params
from ._results import (
    RESULTS as RESULTS,
    is_successful as is_successful,
    result_message as result_message,
    result_name as result_name,
    result_record as result_record,
)
from .identify.base import AbstractBrakingModel as AbstractBrakingModel

# braking data, quarter car, identification (report section 2.2)
from .identify.braking import (
    BrakingData as BrakingData,
    load_braking as load_braking,
    save_braking as save_braking,
    shipped_brakings as shipped_brakings,
)
from .identify.closed_loop import (
    ClosedLoopBraking as ClosedLoopBraking,
    predict_closed_loop as predict_closed_loop,
)
from .identify.fit import (
    FitError as FitError,
    FitResult as FitResult,
    fit_closed_loop as fit_closed_loop,
    fit_open_loop as fit_open_loop,
)
from .identify.open_loop import (
    OpenLoopBraking as OpenLoopBraking,
    predict_open_loop as predict_open_loop,
)
from .params import PRESET_KINDS as PRESET_KINDS, PRESETS as PRESETS, preset as preset
from .robot.controllers import (
    AbstractChainedController as AbstractChainedController,
    AbstractController as AbstractController,
    BoundedController as BoundedController,
    DiscontinuousController as DiscontinuousController,
    MCloskeyMurray93Controller as MCloskeyMurray93Controller,
    MCloskeyMurray97Controller as MCloskeyMurray97Controller,
    PolarController as PolarController,
    PometController as PometController,
    TeelMurrayWalshController as TeelMurrayWalshController,
    TwoStageController as TwoStageController,
    default_controllers as default_controllers,
)
from .robot.khepera import (
    KheperaPlant as KheperaPlant,
    RobotRun as RobotRun,
    ideal_plant as ideal_plant,
    realistic_plant as realistic_plant,
    simulate_robot as simulate_robot,
    simulate_robot_grid as simulate_robot_grid,
)
from .robot.missions import ROBOT_MISSIONS as ROBOT_MISSIONS, Mission as Mission
from .robot.scoring import RunStats as RunStats, score_run as score_run
from .robot.table2 import Table2Scores as Table2Scores
from .robot.unicycle import (
    AbstractSystem as AbstractSystem,
    SystemI as SystemI,
    SystemII as SystemII,
)
from .tire.burckhardt import (
    BurckhardtParams as BurckhardtParams,
    RelaxedBurckhardt as RelaxedBurckhardt,
    burckhardt_mu as burckhardt_mu,
    fit_burckhardt_family as fit_burckhardt_family,
)
from .tire.characteristic import (
    AbstractCharacteristic as AbstractCharacteristic,
    MagicFormula1987Characteristic as MagicFormula1987Characteristic,
    MFCharacteristic as MFCharacteristic,
    tire_characteristic as tire_characteristic,
)
from .tire.distributed import DistributedLuGre as DistributedLuGre

# Combined-slip LuGre, method of moments and Magic Formula (report 2.3-2.4)
from .tire.distributed2d import (
    DistributedLuGre2D as DistributedLuGre2D,
    steady_state_forces as steady_state_forces,
    steady_state_mu_2d as steady_state_mu_2d,
)
from .tire.load import (
    AbstractLoadDistribution as AbstractLoadDistribution,
    AbstractPolynomialLoad as AbstractPolynomialLoad,
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
    solve_steady_state as solve_steady_state,
    stribeck as stribeck,
)
from .tire.lugre2d import (
    LuGre2DParams as LuGre2DParams,
    PointLuGre2D as PointLuGre2D,
    slip_angle as slip_angle,
)
from .tire.lugre2d_fit import (
    MatchResult as MatchResult,
    fit_to_magic_formula as fit_to_magic_formula,
    lugre_initial_guess as lugre_initial_guess,
)
from .tire.lumped2d import LumpedLuGre2D as LumpedLuGre2D
from .tire.magic_formula import (
    MagicFormula1987 as MagicFormula1987,
    MagicFormula1987Params as MagicFormula1987Params,
)
from .tire.moments import (
    MomentLuGre2D as MomentLuGre2D,
    TransitHistory as TransitHistory,
    moments_step_response as moments_step_response,
    simulate_moments_delay as simulate_moments_delay,
    simulate_moments_history as simulate_moments_history,
)
from .tire.relaxed_magic_formula import (
    MagicFormulaParams as MagicFormulaParams,
    RelaxedMagicFormula as RelaxedMagicFormula,
)
from .tire.scaled import (
    FrictionScaleParams as FrictionScaleParams,
    ScaledFriction as ScaledFriction,
)
from .tire.steady_state import (
    braking_mu_uniform as braking_mu_uniform,
    driving_mu_uniform as driving_mu_uniform,
    steady_state_mu as steady_state_mu,
    z_ss as z_ss,
)
from .tire.transient import TireSolution as TireSolution, simulate_tire as simulate_tire
from .tire.uniform_lumped import UniformLumpedLuGre as UniformLumpedLuGre
from .vehicle.normal_load import (
    AbstractNormalLoad as AbstractNormalLoad,
    ConstantLoad as ConstantLoad,
    LoadRelaxation as LoadRelaxation,
    PrescribedLoad as PrescribedLoad,
)
from .vehicle.quarter_car import (
    QuarterCar as QuarterCar,
    QuarterCarSolution as QuarterCarSolution,
    simulate_quarter_car as simulate_quarter_car,
)


# isort: split
# vehicles, simulation, sweeps (report section 2.5)
from ._simulate import Trajectory as Trajectory, simulate as simulate
from ._solution import AbstractSolution as AbstractSolution
from ._sweep import SweepResult as SweepResult, sweep as sweep, sweep_grid as sweep_grid
from .sharding import pad_members as pad_members, sharded_vmap as sharded_vmap
from .solvers import ROS34PW2 as ROS34PW2, ExponentialIntegrator as ExponentialIntegrator
from .tire.friction_ellipse import (
    FrictionEllipseTire as FrictionEllipseTire,
    rally_gravel_tire as rally_gravel_tire,
)
from .tire.isotropic_lumped import IsotropicLumpedLuGre as IsotropicLumpedLuGre
from .tire.linear import LinearTire as LinearTire
from .vehicle.base import AbstractVehicle as AbstractVehicle
from .vehicle.half_car import HalfCar as HalfCar
from .vehicle.maneuvers import (
    brake_in_turn as brake_in_turn,
    half_car_scenario as half_car_scenario,
    step_steer as step_steer,
)
from .vehicle.params import HalfCarParams as HalfCarParams, rally_gravel as rally_gravel
from .vehicle.reduced import ReducedHalfCar as ReducedHalfCar


# isort: split
# optimal driving primitives (report section 2.5, Table 4, Fig. 20)
from .optimal.ip import (
    AbstractStagewiseNLP as AbstractStagewiseNLP,
    IPOptions as IPOptions,
    IPSolution as IPSolution,
    check_linear_variables as check_linear_variables,
    compile_interior_point as compile_interior_point,
    interior_point as interior_point,
    print_iteration_log as print_iteration_log,
)
from .optimal.primitive import Primitive as Primitive
from .optimal.primitives import (
    MAX_EXIT_MU0 as MAX_EXIT_MU0,
    max_exit_primitive as max_exit_primitive,
    min_time_primitive as min_time_primitive,
    multistart_guesses as multistart_guesses,
    point_mass_bound as point_mass_bound,
    primitive_and_bound as primitive_and_bound,
    primitive_options as primitive_options,
)
from .optimal.roads import Road as Road, road as road


# isort: split
# roads from data: centre line and widths (racetrack CSV files, shipped circuits)
from ._road_files import (
    read_road as read_road,
    shipped_tracks as shipped_tracks,
    track as track,
    write_road as write_road,
)
from .optimal.centreline import CentrelineRoad as CentrelineRoad, Gate as Gate


# isort: split
# replay of primitives on the full half-car
from .optimal.replay import (
    Replay as Replay,
    TrackingGains as TrackingGains,
    matched_lugre_tire as matched_lugre_tire,
    replay_open_loop as replay_open_loop,
    replay_tracking as replay_tracking,
)


# isort: split
# minimum-time drives on centre-line roads, in the road's frame (arc length)
from .optimal.curvilinear import (
    CurvilinearManeuverOCP as CurvilinearManeuverOCP,
    CurvilinearPointMassOCP as CurvilinearPointMassOCP,
    RoadPrimitive as RoadPrimitive,
    resample_drive as resample_drive,
    road_point_mass_bound as road_point_mass_bound,
    road_primitive as road_primitive,
    spatial_rhs as spatial_rhs,
    speed_profile as speed_profile,
    speed_profile_guess as speed_profile_guess,
)


# isort: split
# labelled results (xarray, netCDF), sweeps across processes, the compilation cache
from ._compilation import enable_compilation_cache as enable_compilation_cache
from ._result_files import load_result as load_result
from .labelled import (
    primitives_to_xarray as primitives_to_xarray,
    robot_grid_to_xarray as robot_grid_to_xarray,
    sweep_to_xarray as sweep_to_xarray,
    write_netcdf as write_netcdf,
)
from .sharding import gather_members as gather_members


# isort: split
# closing the loop: road surfaces, braking hardware, friction estimation, ABS and
# traction control on the lumped LuGre tire (report section 2.2)
from .control.controllers.braking import (
    AbstractBrakeController as AbstractBrakeController,
    AbstractSlipTracking as AbstractSlipTracking,
    LockedWheel as LockedWheel,
    Measurement as Measurement,
    PeakSlipTracking as PeakSlipTracking,
    RuleBasedABS as RuleBasedABS,
    SlipTracking as SlipTracking,
    track_slip as track_slip,
)
from .control.controllers.peak_seeking import (
    PeakSeekingABS as PeakSeekingABS,
    PeakSeekingState as PeakSeekingState,
)
from .control.controllers.traction import (
    FullThrottle as FullThrottle,
    TractionControl as TractionControl,
    traction_scenario as traction_scenario,
)
from .control.estimation.base import (
    AbstractFrictionEstimator as AbstractFrictionEstimator,
    run_estimator as run_estimator,
)
from .control.estimation.mhe import (
    BrakingRecord as BrakingRecord,
    MHEResult as MHEResult,
    MovingHorizonEstimator as MovingHorizonEstimator,
)
from .control.estimation.observer import (
    FrictionObserver as FrictionObserver,
    ObserverState as ObserverState,
)
from .control.estimation.parametrisation import (
    AbstractRoadParametrisation as AbstractRoadParametrisation,
    FrictionScale as FrictionScale,
    RoadCondition as RoadCondition,
)
from .control.estimation.peak_estimator import (
    BurckhardtBelief as BurckhardtBelief,
    PeakEstimator as PeakEstimator,
    PeakEstimatorState as PeakEstimatorState,
)
from .control.estimation.recorded import (
    FrictionEstimate as FrictionEstimate,
    MeasuredBraking as MeasuredBraking,
    estimate_friction as estimate_friction,
)
from .control.experiments.experiment import braking_experiment as braking_experiment
from .control.experiments.half_car_abs import (
    TurnRun as TurnRun,
    TurnScenario as TurnScenario,
    axle_cars as axle_cars,
    simulate_turn as simulate_turn,
    turn_scenario as turn_scenario,
)
from .control.experiments.metrics import (
    braking_record as braking_record,
    estimate_record as estimate_record,
)
from .control.experiments.mismatch import mismatch_table as mismatch_table
from .control.experiments.scenarios import braking_scenario as braking_scenario
from .control.experiments.tires import OTHER_TIRES as OTHER_TIRES, other_tire as other_tire
from .control.experiments.tuning import tune_gains as tune_gains
from .control.loop import (
    HANDBACK_SPEED as HANDBACK_SPEED,
    STOP_SPEED as STOP_SPEED,
    BrakingRun as BrakingRun,
    closed_loop as closed_loop,
    closed_loop_grid as closed_loop_grid,
    simulate_braking as simulate_braking,
    simulate_braking_grid as simulate_braking_grid,
    stack as stack,
)
from .control.plant.hardware import (
    MAX_DELAY as MAX_DELAY,
    BrakeHardware as BrakeHardware,
    ideal_hardware as ideal_hardware,
    realistic_hardware as realistic_hardware,
)
from .control.plant.quarter_car import (
    BrakingScenario as BrakingScenario,
    SurfaceChange as SurfaceChange,
    braking_quarter_car as braking_quarter_car,
)
from .control.road.bound import (
    actuated_limit as actuated_limit,
    physical_limit as physical_limit,
    traction_limit as traction_limit,
)
from .control.road.peak import (
    braking_curve as braking_curve,
    peak_braking as peak_braking,
    peak_driving as peak_driving,
)
from .control.road.surfaces import (
    SURFACES as SURFACES,
    Surface as Surface,
    surface as surface,
)


# isort: split
# the car driven on the move: plant with varying grip, actuators, sensors, grip estimation
from .drive.actuators import (
    DriveActuators as DriveActuators,
    DriveActuatorState as DriveActuatorState,
    ideal_actuators as ideal_actuators,
)
from .drive.axle_peak import (
    AxlePeakEstimator as AxlePeakEstimator,
    AxlePeakState as AxlePeakState,
    CautiousGripEstimator as CautiousGripEstimator,
    CautiousGripState as CautiousGripState,
)
from .drive.baselines import (
    PrimitiveReference as PrimitiveReference,
    PrimitiveTracker as PrimitiveTracker,
    command_lead as command_lead,
    nominal_primitive as nominal_primitive,
    offline_bound as offline_bound,
    open_loop_schedule as open_loop_schedule,
    primitive_reference as primitive_reference,
)
from .drive.estimator import (
    AbstractAxleEstimator as AbstractAxleEstimator,
    AbstractGripEstimator as AbstractGripEstimator,
    AxleGripEstimator as AxleGripEstimator,
    AxleGripState as AxleGripState,
    GripEstimate as GripEstimate,
    longitudinal_capacity as longitudinal_capacity,
    peak_friction as peak_friction,
    scale_of_peak as scale_of_peak,
    scaled_steady_state_mu as scaled_steady_state_mu,
    side_peak_friction as side_peak_friction,
    slip_velocity_std as slip_velocity_std,
)
from .drive.grip import (
    AbstractGripField as AbstractGripField,
    GripPatches as GripPatches,
    GripProfile as GripProfile,
    PeakRatios as PeakRatios,
    RelativeGrip as RelativeGrip,
    SurfaceFactor as SurfaceFactor,
    UniformGrip as UniformGrip,
    scale_friction as scale_friction,
)
from .drive.horizon import (
    HorizonOCP as HorizonOCP,
    HorizonState as HorizonState,
    RecedingHorizonDriver as RecedingHorizonDriver,
    RoadTable as RoadTable,
    axle_slips as axle_slips,
    fit_planner_tire as fit_planner_tire,
    horizon_problem as horizon_problem,
    planner_car as planner_car,
    profile_guess as profile_guess,
    scaled_planning_car as scaled_planning_car,
    shift_multipliers as shift_multipliers,
    shift_plan as shift_plan,
)
from .drive.metrics import (
    DriveOutcome as DriveOutcome,
    EndGate as EndGate,
    drive_outcome as drive_outcome,
    drive_path as drive_path,
    drive_time as drive_time,
    max_distance_off_road as max_distance_off_road,
    path_departure as path_departure,
    pose_departures as pose_departures,
)
from .drive.plant import (
    DrivePlant as DrivePlant,
    DriveState as DriveState,
    drive_step as drive_step,
    init_drive as init_drive,
    measure_drive as measure_drive,
)
from .drive.plant_tires import (
    mf_plant_tire as mf_plant_tire,
    peak_surface_factor as peak_surface_factor,
)
from .drive.scenarios import (
    CONVERGED_REPLAN_KKT as CONVERGED_REPLAN_KKT,
    CORNER_DRIVER as CORNER_DRIVER,
    DRIVER_PROBE_DISTANCE as DRIVER_PROBE_DISTANCE,
    DRIVER_TRACTION_LIMIT as DRIVER_TRACTION_LIMIT,
    FAST_ROAD_DRIVER as FAST_ROAD_DRIVER,
    FILE_ROAD_DRIVER as FILE_ROAD_DRIVER,
    DriveScenario as DriveScenario,
    PatchedProfile as PatchedProfile,
    ScenarioGrip as ScenarioGrip,
    drive_scenario as drive_scenario,
    driver_estimator as driver_estimator,
    driver_settings as driver_settings,
    main_corner as main_corner,
    nominal_scale as nominal_scale,
    plant_peak as plant_peak,
    plant_surface_factor as plant_surface_factor,
    scale_for_peak as scale_for_peak,
    scenario_driver as scenario_driver,
    scenario_grip as scenario_grip,
    scenario_road as scenario_road,
)
from .drive.sensors import DriveMeasurement as DriveMeasurement, DriveSensors as DriveSensors
from .drive.simulate import (
    AbstractDriveController as AbstractDriveController,
    CommandSchedule as CommandSchedule,
    DriveRun as DriveRun,
    PathFollower as PathFollower,
    simulate_drive as simulate_drive,
)


# isort: split
# tyre property files (.tir) and the Magic Formula 5.2 / 6.1 / 6.2
from .tire.mf6 import (
    MFLongitudinalTire as MFLongitudinalTire,
    MFOutput as MFOutput,
    MFParams as MFParams,
    MFTire as MFTire,
    RelaxedMFTire as RelaxedMFTire,
    mf_evaluate as mf_evaluate,
    mf_forces as mf_forces,
    mf_relaxation_lengths as mf_relaxation_lengths,
    mf_summary as mf_summary,
)
from .tire.tir import (
    TirEntry as TirEntry,
    TirError as TirError,
    TirFile as TirFile,
    TirSection as TirSection,
    format_tir as format_tir,
    parse_tir as parse_tir,
    read_tir as read_tir,
    shipped_tires as shipped_tires,
    write_tir as write_tir,
)


try:
    __version__ = _version("vehsim")
except _PackageNotFoundError:  # run from a source tree that was never installed
    __version__ = "0+unknown"
