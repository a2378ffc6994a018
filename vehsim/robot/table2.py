r"""Our Table 2 against the report's: letters per cell, the matching cells, the four findings.

A Monte-Carlo grid (`simulate_robot_grid` over `ROBOT_MISSIONS` x seeds) is scored run by
run (`score_run`); a cell (controller, system, mission) takes the majority letter of its
seeds. A cell is *comparable* when the report gives one letter for it: controllers 1-3 and
5-8 on System I and II and each mission (a report row "I/II" holds for both systems),
56 cells; controller 4's row, "E in x, y, O in $\gamma$", gives 4 more, one per mission,
matched when the position alone scores E *and* the heading alone scores O (controller 4
ignores the system; its System I runs are used).

The four findings of the report's text after Table 2, each made a test on the scores:

1. *"Controller 2 gave the most satisfactory performance for all missions"*: on System II
   controller 2's mean letter rank (E = 0, G, S, C, O, U = 5, over missions and seeds) is the
   lowest of the eight (ties count as lowest).
2. *"Time-varying controllers ... showed slow convergence"*: the median convergence time
   $t_c$ of controllers 5-8 (runs that never settle count as infinite) exceeds `FAST_TIME`
   and that of controllers 1-4.
3. *"Controller 4 was sensitive to sensor noise resulting in relatively large limit cycles
   of the heading angle around the origin"*: its median worst heading error over the last
   `SETTLE_WINDOW` exceeds `HEADING_TOL` (a limit cycle beyond the tolerance: "O in
   $\gamma$") and twice the same on the `reference` grid, the plant with the pose measured
   exactly.
4. *Controller 6 "diverged" on System I*: its System I letter is U on at least 3 of the 4
   missions.
"""

from __future__ import annotations

import dataclasses

import jax
import numpy as np

from .missions import ROBOT_MISSIONS
from .scoring import FAST_TIME, HEADING_TOL, LETTERS, SETTLE_WINDOW, RunStats, score_run


#: Report Table 2 (controller -> system -> letters for missions E, N, S, L).
REPORT_TABLE2 = {
    1: {"I": "EOOO", "II": "EEEE"},
    2: {"I": "EOOO", "II": "EEEE"},
    3: {"I": "CCCO", "II": "CCCC"},
    4: {"Polar": "E in x,y; O in gamma"},
    5: {"I/II": "GSSO"},
    6: {"I": "UUUU", "II": "SSSS"},
    7: {"I/II": "SSSO"},
    8: {"I/II": "GGGG"},
}

SYSTEMS = ("I", "II")

HEADLINE_FINDINGS = ("controller2_most_satisfactory", "time_varying_slow",
                     "controller4_noise_sensitive", "controller6_diverges_on_system_I")
"""Names of the report's four headline findings, in the order of the module docstring."""


def report_letters(controller: int, system: str) -> str | None:
    """The report's four letters (E, N, S, L) for `controller` (1-8) on `system` ("I" or
    "II"), or None where it gives none (controller 4)."""
    row = REPORT_TABLE2[controller]
    letters = row.get(system) or row.get("I/II")
    return letters if letters is not None and len(letters) == 4 else None


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


def table2_agreement(scores: Table2Scores) -> dict:
    """Cells whose majority letter equals the report's (module docstring).

    **Returns:** `{"matching_cells": int, "comparable_cells": int, "differing": [...]}`,
    the differing cells as "controller-system-mission" strings (e.g. "1-I-N").
    """
    matching, comparable, differing = 0, 0, []
    for c in range(8):
        for s, sys_name in enumerate(SYSTEMS):
            rep = report_letters(c + 1, sys_name)
            if c == 3 and s == 0:  # "E in x, y, O in gamma"
                ours = zip(scores.letters(c, s, scores.codes_position),
                           scores.letters(c, s, scores.codes_heading))
                hits = [p == "E" and h == "O" for p, h in ours]
            elif rep is None:
                continue
            else:
                hits = [a == b for a, b in zip(scores.letters(c, s), rep)]
            comparable += len(hits)
            matching += sum(hits)
            differing += [f"{c + 1}-{sys_name}-{ROBOT_MISSIONS[m].name[0]}"
                          for m, hit in enumerate(hits) if not hit]
    return {"matching_cells": matching, "comparable_cells": comparable,
            "differing": differing}


def _median_tc(scores: Table2Scores, controllers) -> float:
    tc = np.where(scores.settled[controllers], scores.tc[controllers], np.inf)
    return float(np.median(tc))


def headline_findings(scores: Table2Scores, reference: Table2Scores) -> dict:
    """The report's four findings, each reproduced or not (module docstring), with the
    numbers that decide it. `reference`: the same grid on the plant with the pose measured
    exactly (for finding 3).

    **Returns:** `{name: {"reproduced": bool, ...numbers}}` for the names of
    `HEADLINE_FINDINGS`.
    """
    rank = scores.mean_rank()[:, 1]
    tv, ti = _median_tc(scores, slice(4, 8)), _median_tc(scores, slice(0, 4))
    wh = float(np.median(scores.window_heading_deg[3]))
    wh_ref = float(np.median(reference.window_heading_deg[3]))
    c6 = scores.letters(5, 0)
    return {
        "controller2_most_satisfactory": {
            "reproduced": bool(rank[1] <= rank.min()),
            "mean_letter_rank_system_II": rank.tolist()},
        "time_varying_slow": {
            "reproduced": bool(tv > FAST_TIME and tv > ti),
            "median_t_c_controllers_5_8_s": tv, "median_t_c_controllers_1_4_s": ti},
        "controller4_noise_sensitive": {
            "reproduced": bool(wh > np.degrees(HEADING_TOL) and wh > 2 * wh_ref),
            "median_heading_window_deg": wh, "median_heading_window_exact_pose_deg": wh_ref},
        "controller6_diverges_on_system_I": {
            "reproduced": c6.count("U") >= 3, "letters_system_I": c6},
    }
