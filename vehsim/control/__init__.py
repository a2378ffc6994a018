"""Closing the loop on the LuGre models: road surfaces, braking hardware, friction
estimation, ABS and traction control (report section 2.2)."""
