"""Braking data and parameter identification through the simulator (report section 2.2)."""
