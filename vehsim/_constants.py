"""Physical constants shared by the models."""

GRAVITY = 9.81
"""Gravitational acceleration [m/s^2], the value of the benchmark maneuvers' definition."""
