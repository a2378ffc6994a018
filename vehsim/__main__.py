"""`python -m vehsim`: the command line (`vehsim.cli`)."""

from .cli import run


run()
