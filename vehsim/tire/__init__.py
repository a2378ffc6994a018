"""Tire friction models (report sections 2.2-2.4)."""
