"""Closing the loop on the LuGre models (report section 2.2): braking and traction control
with friction estimation, on a plant that behaves like hardware.

The folder follows the loop:

- `road`: what the tire meets: named road surfaces, the peak of any tire's steady-state
  force-slip curve and the physical and actuated limits of a braking;
- `plant`: the braked quarter car between control samples, the brake actuator, the wheel
  and speed sensors, and the stiff integrator of one sample;
- `estimation`: the friction observer and the moving-horizon estimator of the road;
- `controllers`: ABS and traction controllers, sampled at the hardware's rate;
- `loop.py`: the closed loop itself, one `lax.scan` over samples;
- `experiments`: named scenarios, plant tires of other shapes (`other_tire`), one braking
  judged against its limit, the records and metrics, gradient tuning of the gains, and ABS
  on the half car in a turn.
"""
