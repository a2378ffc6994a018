"""Table 2 scoring on synthetic trajectories of each kind."""

import jax.numpy as jnp
import numpy as np
import pytest

from vehsim.robot import scoring
from vehsim.robot.scoring import LETTERS, score_trajectory


T, DT = 40.0, 0.02
TS = np.arange(0.0, T, DT)


def _decay(tau, x0=(-0.15, 0.05, 0.5)):
    """Monotone exponential convergence with time constant tau, smooth commands."""
    e = np.exp(-TS / tau)[:, None]
    poses = np.asarray(x0)[None] * e
    commands = np.stack([0.15 / tau * e[:, 0], 0.5 / tau * e[:, 0]], axis=1)
    return poses, commands


def _letter(poses, commands, **kw):
    return LETTERS[int(score_trajectory(jnp.asarray(TS), poses, commands, **kw))]


def test_excellent():
    assert _letter(*_decay(1.0)) == "E"


def test_good_oscillating_but_fast():
    poses, commands = _decay(1.0)
    wiggle = 0.05 * np.sin(2 * np.pi * TS) * np.exp(-TS / 3.0)
    poses = poses.copy()
    poses[:, 0] += wiggle                    # several crossings of x = 0, settles by ~5 s
    assert _letter(poses, commands) == "G"


def test_good_not_fast_enough_for_excellent():
    assert _letter(*_decay(5.0)) == "G"      # enters tolerance at ~14 s (10 < t_c < 20)


def test_slow():
    assert _letter(*_decay(8.0)) == "S"      # t_c ~ 22 s > SLOW_TIME


def test_chattering():
    poses, commands = _decay(1.0)
    commands = commands.copy()
    commands[:, 1] += 0.5 * (-1.0) ** np.arange(TS.size)   # bang-bang flips each sample
    assert _letter(poses, commands) == "C"


def test_oscillatory():
    poses = np.stack([0.02 * np.sin(TS), 0.01 * np.cos(TS), 0.1 * np.sin(2 * TS)], axis=1)
    commands = np.stack([0.02 * np.cos(TS), 0.2 * np.cos(2 * TS)], axis=1)
    assert _letter(poses, commands) == "O"


def test_unstable():
    poses = np.stack([0.01 * np.exp(TS / 10), 0.0 * TS, 0.0 * TS], axis=1)
    commands = np.zeros((TS.size, 2))
    assert _letter(poses, commands) == "U"
    nan = _decay(1.0)[0].copy()
    nan[-1, 0] = np.nan
    assert _letter(nan, _decay(1.0)[1]) == "U"


def test_position_only_and_heading_only():
    """'E in x, y, O in gamma' (controller 4 in Table 2) is expressible."""
    poses, commands = _decay(1.0)
    poses = poses.copy()
    poses[:, 2] = 0.3 * np.sin(3 * TS)      # heading limit cycle of 17 deg
    assert _letter(poses, commands, heading=False) == "E"
    assert _letter(poses, commands, position=False) == "O"
    assert _letter(poses, commands) == "O"


@pytest.mark.parametrize("tau", [0.5, 2.0])
def test_thresholds_are_what_the_letters_use(tau):
    """t_c of an exponential decay is where it last leaves the tolerance box."""
    poses, commands = _decay(tau)
    stats = scoring.accumulate(jnp.asarray(TS), poses, commands)
    expected = max(tau * np.log(np.hypot(0.15, 0.05) / scoring.POSITION_TOL),
                   tau * np.log(0.5 / scoring.HEADING_TOL))
    assert abs(float(stats.convergence_time()) - expected) <= DT + 1e-9
