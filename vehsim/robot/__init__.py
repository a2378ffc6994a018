"""Unicycle robot controllers on a realistic Khepera plant (report section 2.1)."""
