"""Runs of the closed loop that answer a question: named scenarios, a braking judged against
its limit, records and metrics, gradient tuning of the gains, ABS in a turn."""
