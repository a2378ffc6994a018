"""Solvers for the stiff parts of vehsim's models, as diffrax solvers."""

from .exponential import (
    ExponentialIntegrator as ExponentialIntegrator,
    StepMapSolver as StepMapSolver,
    StepMapTerm as StepMapTerm,
)
from .rosenbrock import ROS34PW2 as ROS34PW2, solve_small as solve_small
