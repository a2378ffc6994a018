"""Vehicle models (report section 2.5): half-car with wheel and suspension dynamics, reduced."""
