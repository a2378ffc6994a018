"""Physical constants shared by the models, and the ranges the readers of records share."""

GRAVITY = 9.81
"""Gravitational acceleration [m/s^2], the value of the benchmark maneuvers' definition."""

SAMPLE_STEP_RANGE = (1e-5, 1.0)
"""The mean sample step [s] of a braking record, and the estimator's ``--sample-time``:
from 100 kHz to 1 Hz. A step outside is most likely a time column in another unit
(milliseconds read as seconds, or the reverse), where a fit or an estimator would integrate
the wheel across seconds at a step or follow it for microseconds."""
