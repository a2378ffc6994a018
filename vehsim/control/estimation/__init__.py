"""Estimating the road condition from what the wheel measures: a nonlinear observer and a
moving-horizon estimator."""
