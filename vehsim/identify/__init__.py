"""Braking data and parameter identification through the simulator (report section 2.2).

`braking` (the data), `parameters` (the fitted quantities and their unconstrained
coordinates), `friction_state` and `sensitivities` (eq. 22 on the data grid and its
derivatives), `open_loop` and `closed_loop` (the two braking models), `levenberg_marquardt`,
`diagnostics` and `fit` (the fits and their results).
"""
