"""The plant as hardware sees it: the braked quarter car, the actuator, the sensors, and the
stiff integration of one control sample."""
