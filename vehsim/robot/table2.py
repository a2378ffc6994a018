r"""Scores of a Monte-Carlo grid for Table 2: letters per run and per cell.

A Monte-Carlo grid (`simulate_robot_grid` over `ROBOT_MISSIONS` x seeds) is scored run by
run (`score_run`); a cell (controller, system, mission) takes the majority letter of its
seeds. The comparison with the report's Table 2 and its four findings is report-only: it
lives with the report section, `vehsim.reproduce.robot`.
"""

from __future__ import annotations

import dataclasses

import jax
import numpy as np

from .missions import ROBOT_MISSIONS
from .scoring import LETTERS, SETTLE_WINDOW, RunStats, score_run


def _codes(stats: RunStats, **kw):
    return np.asarray(jax.vmap(jax.vmap(jax.vmap(lambda s: score_run(s, **kw))))(stats))


@dataclasses.dataclass
class Table2Scores:
    """Scores of a grid, each array shaped (controller, system, mission, seed): letter codes
    of the whole pose (`codes`), of the position alone and of the heading alone, the
    convergence time `tc` [s] and whether the run `settled`, the command reversal `rate`
    [1/s], the worst position [mm] and heading [deg] errors over the last `SETTLE_WINDOW`,
    and the most zero `crossings` of a coordinate. Build it with `from_stats`."""

    codes: np.ndarray
    codes_position: np.ndarray
    codes_heading: np.ndarray
    tc: np.ndarray
    settled: np.ndarray
    rate: np.ndarray
    window_position_mm: np.ndarray
    window_heading_deg: np.ndarray
    crossings: np.ndarray

    @property
    def n_seeds(self) -> int:
        return self.codes.shape[3]

    @classmethod
    def from_stats(cls, stats: RunStats, n_seeds: int) -> Table2Scores:
        """The scores of `stats`, the `RunStats` of a grid with leading axes (8 controllers,
        2 systems, runs) whose first `len(ROBOT_MISSIONS) * n_seeds` runs are the missions'
        seeds in mission order (runs after them are ignored)."""
        n_m = len(ROBOT_MISSIONS)
        st = jax.tree_util.tree_map(lambda a: a[:, :, : n_m * n_seeds], stats)

        def shaped(a):
            return np.asarray(a).reshape((8, 2, n_m, n_seeds))

        return cls(
            codes=shaped(_codes(st)), codes_position=shaped(_codes(st, heading=False)),
            codes_heading=shaped(_codes(st, position=False)),
            tc=shaped(st.convergence_time()),
            settled=shaped(st.convergence_time() <= st.t_final - SETTLE_WINDOW),
            rate=shaped(np.asarray(st.reversals).sum(-1) / np.asarray(st.t_final)),
            window_position_mm=shaped(1e3 * np.asarray(st.window_position)),
            window_heading_deg=shaped(np.degrees(np.asarray(st.window_heading))),
            crossings=shaped(np.asarray(st.crossings).max(-1)))

    def majority(self, c: int, s: int, m: int, codes=None) -> tuple[int, float]:
        """(majority code, share of seeds with it) of cell (c, s, m), 0-based indices."""
        codes = self.codes if codes is None else codes
        counts = np.bincount(codes[c, s, m].ravel(), minlength=len(LETTERS))
        return int(np.argmax(counts)), float(counts.max() / self.n_seeds)

    def letters(self, c: int, s: int, codes=None) -> str:
        """Majority letter per mission of controller `c` on system `s` (0-based)."""
        codes = self.codes if codes is None else codes
        return "".join(LETTERS[self.majority(c, s, m, codes)[0]]
                       for m in range(codes.shape[2]))

    def mean_rank(self):
        """Mean letter code (E = 0 ... U = 5) per (controller, system)."""
        return self.codes.astype(float).mean(axis=(2, 3))
