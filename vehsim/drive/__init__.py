"""A car driven on the move: the half-car plant with position-dependent grip, actuators and
noisy sensors, a sampled-data driver loop, and grip estimation from the axles' forces."""
