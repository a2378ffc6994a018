"""What the tire meets: road surfaces, the peak of the force-slip curve, the braking limits."""
