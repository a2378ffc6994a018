r"""Automatic scoring of a robot run into the categories of report Table 2.

The report's letters (section 2.1): **E** excellent (fast, no oscillation in $x$, $y$ or
$\gamma$, reasonable inputs, natural paths), **G** good (converged within 10 s),
**S** slow (converged after more than 20 s), **C** chattering (converged, but the velocity
commands chatter), **O** oscillatory (stays around the origin without converging),
**U** unstable or unsatisfactory. The thresholds below make these words into numbers; they
are the only tuning of the scoring and are named so a reader can change them.

The statistics are accumulated *during* the simulation (`RunStats.update`, called once
per control sample inside the `lax.scan`), so a Monte-Carlo grid of thousands of runs
never stores trajectories; `score_trajectory` runs the same update over a stored
trajectory (used by the tests on synthetic trajectories).
"""

from __future__ import annotations

import functools as ft

import equinox as eqx
import jax
import jax.numpy as jnp
from jaxtyping import Array, Bool, Float, Int

from .._math import safe_hypot, wrap_angle


LETTERS = "EGSCOU"
"""Letter of each score code: 0 E, 1 G, 2 S, 3 C, 4 O, 5 U."""

#: A run has converged at time t_c if from t_c on |(x, y)| <= POSITION_TOL [m] ...
POSITION_TOL = 0.010
#: ... and |gamma| <= HEADING_TOL [rad] (10 deg: the 8.3 mm/s speed quantum of the Khepera
#: leaves a heading dead band of several degrees at unit gain).
HEADING_TOL = 0.175
#: ... and it must stay converged for at least this long before the end of the run [s].
SETTLE_WINDOW = 5.0
#: E needs t_c <= FAST_TIME [s]; G is "acceptable, within 10 s" (report).
FAST_TIME = 10.0
#: S: "more than 20 s" (report). Runs converging between FAST_TIME and SLOW_TIME (which the
#: report leaves unassigned) are counted G.
SLOW_TIME = 20.0
#: Zero crossings of x, y or gamma are counted with a hysteresis band (a crossing is a move
#: from above +band to below -band or back), so sensor noise does not count.
CROSSING_BAND = (0.005, 0.005, 0.05)
#: E allows at most this many crossings of each of x, y, gamma ("no oscillations").
MAX_CROSSINGS_EXCELLENT = 2
#: A command reversal is a sign change of the step-to-step command increment with both
#: increments larger than this, in (v [m/s], omega [rad/s]).
CHATTER_STEP = (0.02, 0.3)
#: C if the reversals (of v and omega together) exceed this rate [1/s] over the run.
CHATTER_RATE = 0.5
#: E needs peak |v| <= REASONABLE_V [m/s] and peak |omega| <= REASONABLE_OMEGA [rad/s].
REASONABLE_V = 0.5
REASONABLE_OMEGA = 6.0
#: Not converged but within these bounds over the last SETTLE_WINDOW: O; else U.
OSCILLATION_POSITION = 0.05
OSCILLATION_HEADING = 0.8


class RunStats(eqx.Module):
    """Running statistics of one run, enough to score it (all arrays; vmappable)."""

    t_final: Float[Array, ""]
    t_out_position: Float[Array, ""]
    t_out_heading: Float[Array, ""]
    side: Float[Array, 3]
    crossings: Int[Array, 3]
    previous_command: Float[Array, 2]
    previous_increment: Float[Array, 2]
    reversals: Int[Array, 2]
    peak_command: Float[Array, 2]
    window_position: Float[Array, ""]
    window_heading: Float[Array, ""]
    finite: Bool[Array, ""]
    started: Bool[Array, ""]

    @classmethod
    def init(cls, t_final) -> RunStats:
        t_final = jnp.asarray(t_final, dtype=float)
        z = jnp.zeros_like(t_final)
        return cls(
            t_final=t_final, t_out_position=z, t_out_heading=z, side=jnp.zeros(3, z.dtype),
            crossings=jnp.zeros(3, int), previous_command=jnp.zeros(2, z.dtype),
            previous_increment=jnp.zeros(2, z.dtype), reversals=jnp.zeros(2, int),
            peak_command=jnp.zeros(2, z.dtype), window_position=z, window_heading=z,
            finite=jnp.array(True), started=jnp.array(False),
        )

    def update(self, t, pose: Float[Array, 3], command: Float[Array, 2]) -> RunStats:
        """Account for the true `pose` at time `t` and the `command` (v, omega) issued then."""
        dt = jnp.asarray(t, dtype=self.t_final.dtype)
        position_error = safe_hypot(pose[0], pose[1])
        heading_error = jnp.abs(wrap_angle(pose[2]))
        t_out_position = jnp.where(
            position_error > POSITION_TOL, dt, self.t_out_position)
        t_out_heading = jnp.where(heading_error > HEADING_TOL, dt, self.t_out_heading)
        band = jnp.asarray(CROSSING_BAND, dtype=pose.dtype)
        coord = jnp.stack([pose[0], pose[1], wrap_angle(pose[2])])
        new_side = jnp.where(coord > band, 1.0, jnp.where(coord < -band, -1.0, self.side))
        crossed = (new_side != self.side) & (self.side != 0)
        increment = command - self.previous_command
        big = (jnp.abs(increment) > jnp.asarray(CHATTER_STEP, dtype=pose.dtype)) & (
            jnp.abs(self.previous_increment) > jnp.asarray(CHATTER_STEP, dtype=pose.dtype))
        reversal = big & (increment * self.previous_increment < 0) & self.started
        in_window = dt >= self.t_final - SETTLE_WINDOW
        finite = self.finite & jnp.all(jnp.isfinite(pose)) & jnp.all(jnp.isfinite(command))
        return RunStats(
            t_final=self.t_final, t_out_position=t_out_position, t_out_heading=t_out_heading,
            side=new_side, crossings=self.crossings + crossed.astype(int),
            previous_command=command,
            previous_increment=jnp.where(self.started, increment, jnp.zeros_like(increment)),
            reversals=self.reversals + reversal.astype(int),
            peak_command=jnp.maximum(self.peak_command, jnp.abs(command)),
            window_position=jnp.where(in_window, jnp.maximum(self.window_position,
                                                             position_error),
                                      self.window_position),
            window_heading=jnp.where(in_window, jnp.maximum(self.window_heading,
                                                            heading_error),
                                     self.window_heading),
            finite=finite, started=jnp.array(True),
        )

    def with_command_statistics(self, other: RunStats) -> RunStats:
        """These statistics with those of the commands alone (`previous_command`,
        `previous_increment`, `reversals`, `peak_command`, `started`) taken from `other`:
        two scorings of one run (its true pose and its odometry) share them."""
        def fields(s):
            return (s.previous_command, s.previous_increment, s.reversals, s.peak_command,
                    s.started)

        return eqx.tree_at(fields, self, fields(other))

    def convergence_time(self, position: bool = True, heading: bool = True):
        """Time after which the pose stays within tolerance (t_c)."""
        tp = self.t_out_position if position else jnp.zeros_like(self.t_out_position)
        th = self.t_out_heading if heading else jnp.zeros_like(self.t_out_heading)
        return jnp.maximum(tp, th)


def score_run(stats: RunStats, position: bool = True, heading: bool = True) -> Int[Array, ""]:
    """The Table 2 letter code of a run (index into `LETTERS`).

    Decision (first match): not converged -> O if it stays within (OSCILLATION_POSITION,
    OSCILLATION_HEADING) of the origin over the last SETTLE_WINDOW, else U; chattering
    commands -> C; t_c > SLOW_TIME -> S; t_c <= FAST_TIME with at most
    MAX_CROSSINGS_EXCELLENT crossings per coordinate and reasonable peak inputs -> E; else G.
    `position`/`heading` = False scores one part of the pose alone (as the report does for
    controller 4: "E in x, y, O in gamma").
    """
    t_c = stats.convergence_time(position, heading)
    converged = stats.finite & (t_c <= stats.t_final - SETTLE_WINDOW)
    near = stats.finite
    if position:
        near = near & (stats.window_position <= OSCILLATION_POSITION)
    if heading:
        near = near & (stats.window_heading <= OSCILLATION_HEADING)
    rate = jnp.sum(stats.reversals) / stats.t_final
    chatter = rate > CHATTER_RATE
    which = jnp.array([position, position, heading])
    crossings = jnp.max(jnp.where(which, stats.crossings, 0))
    reasonable = (stats.peak_command[0] <= REASONABLE_V) & (
        stats.peak_command[1] <= REASONABLE_OMEGA)
    excellent = (t_c <= FAST_TIME) & (crossings <= MAX_CROSSINGS_EXCELLENT) & reasonable
    converged_code = jnp.where(chatter, 3, jnp.where(t_c > SLOW_TIME, 2,
                                                     jnp.where(excellent, 0, 1)))
    return jnp.where(converged, converged_code, jnp.where(near, 4, 5))


@ft.partial(jax.jit, static_argnames=("position", "heading"))
def score_trajectory(ts, poses, commands, position: bool = True, heading: bool = True):
    """Score a stored trajectory: `ts` (n,), `poses` (n, 3), `commands` (n, 2)."""
    return score_run(accumulate(ts, poses, commands), position, heading)


@jax.jit
def accumulate(ts, poses, commands) -> RunStats:
    """`RunStats` of a stored trajectory (the run ends at ts[-1] + (ts[1] - ts[0]))."""
    ts = jnp.asarray(ts, dtype=float)
    t_final = ts[-1] + (ts[1] - ts[0])

    def body(stats, xs):
        return stats.update(*xs), None

    stats, _ = jax.lax.scan(body, RunStats.init(t_final),
                            (ts, jnp.asarray(poses, dtype=float),
                             jnp.asarray(commands, dtype=float)))
    return stats


def letters(codes) -> str | list:
    """Letters of an array of score codes (nested lists for arrays of rank > 1)."""
    import numpy as np

    codes = np.asarray(codes)
    if codes.ndim == 0:
        return LETTERS[int(codes)]
    return [letters(c) for c in codes]
