"""Optimal driving primitives (report section 2.5, Table 4, Fig. 20).

`roads` (the benchmark corridors and boundary sets), `centreline` (roads given by a centre
line and widths: racetrack data, gates), `shooting` (the maneuver problems by
direct multiple shooting), `ip` (the structured interior-point method), `guesses` (initial
guesses), `primitives` (the solves), `primitive` (a solved maneuver and its record),
`replay` (a primitive's torques on the full half-car) and `curvilinear` (drives on
centre-line roads in the road's frame). The public names are exported flat from `vehsim`.
"""
