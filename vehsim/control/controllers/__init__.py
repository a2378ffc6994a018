"""Brake (ABS) and traction controllers, sampled at the hardware's rate."""
