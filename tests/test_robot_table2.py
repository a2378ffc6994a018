"""Table 2 agreement and the report's four findings, on scores whose answer is known."""

import dataclasses

import numpy as np

from vehsim.reproduce.robot import (
    _WHY,
    HEADLINE_FINDINGS,
    SYSTEMS,
    _count,
    headline_findings,
    report_letters,
    table2_agreement,
)
from vehsim.robot.scoring import LETTERS
from vehsim.robot.table2 import Table2Scores


SEEDS = 3


def _report_scores() -> Table2Scores:
    """Every seed scores the report's letter; controller 4 'E in x, y, O in gamma'; the
    time-invariant laws settle at 3 s, the time-varying ones at 25 s; controller 4's heading
    cycles 30 deg wide."""
    codes = np.zeros((8, 2, 4, SEEDS), int)
    for c in range(8):
        for s, name in enumerate(SYSTEMS):
            rep = report_letters(c + 1, name) or "OOOO"
            codes[c, s] = np.array([LETTERS.index(x) for x in rep])[:, None]
    position, heading = codes.copy(), codes.copy()
    position[3], heading[3] = LETTERS.index("E"), LETTERS.index("O")
    shape = codes.shape
    tc = np.where(np.arange(8)[:, None, None, None] < 4, 3.0, 25.0) * np.ones(shape)
    window_heading = np.full(shape, 2.0)
    window_heading[3] = 30.0
    return Table2Scores(codes=codes, codes_position=position, codes_heading=heading, tc=tc,
                        settled=np.ones(shape, bool), rate=np.zeros(shape),
                        window_position_mm=np.ones(shape), window_heading_deg=window_heading,
                        crossings=np.zeros(shape, int))


def test_the_report_agrees_with_itself_and_a_changed_cell_is_named():
    """7 controllers x 2 systems x 4 missions with one letter each, plus controller 4's four
    missions: 60 comparable cells. Changing one seed of three leaves the majority; changing
    two of three moves the cell."""
    scores = _report_scores()
    assert table2_agreement(scores) == {"matching_cells": 60, "comparable_cells": 60,
                                        "differing": []}
    codes = scores.codes.copy()
    codes[5, 0, 2, :1] = LETTERS.index("G")          # controller 6, System I, Singular
    assert table2_agreement(dataclasses.replace(scores, codes=codes))["matching_cells"] == 60
    codes[5, 0, 2, :2] = LETTERS.index("G")
    moved = table2_agreement(dataclasses.replace(scores, codes=codes))
    assert moved["matching_cells"] == 59 and moved["differing"] == ["6-I-S"]
    heading = scores.codes_heading.copy()
    heading[3, 0, 0] = LETTERS.index("E")             # controller 4 converges in heading
    assert table2_agreement(dataclasses.replace(scores, codes_heading=heading))[
        "differing"] == ["4-I-E"]


def test_headline_findings_follow_their_definitions():
    scores = _report_scores()
    exact = dataclasses.replace(scores, window_heading_deg=np.full(scores.codes.shape, 2.0))
    found = headline_findings(scores, exact)
    assert [found[k]["reproduced"] for k in HEADLINE_FINDINGS] == [True] * 4
    # controllers 1 and 2 tie on System II (EEEE): ties count as the most satisfactory
    rank = found["controller2_most_satisfactory"]["mean_letter_rank_system_II"]
    assert rank[0] == rank[1] == 0.0
    assert found["time_varying_slow"]["median_t_c_controllers_5_8_s"] == 25.0
    # each finding fails when its numbers say so
    worse = scores.codes.copy()
    worse[1, 1, 0] = LETTERS.index("G")
    same_noise = dataclasses.replace(scores, window_heading_deg=exact.window_heading_deg)
    fast = dataclasses.replace(scores, tc=np.full(scores.codes.shape, 3.0))
    only_5_8_settle = np.broadcast_to(np.arange(8)[:, None, None, None] >= 4,
                                      scores.codes.shape)
    unsettled = dataclasses.replace(scores, settled=only_5_8_settle)
    converging = scores.codes.copy()
    converging[5, 0, :2] = LETTERS.index("S")
    cases = [(dataclasses.replace(scores, codes=worse), "controller2_most_satisfactory"),
             (fast, "time_varying_slow"),
             (same_noise, "controller4_noise_sensitive"),
             (dataclasses.replace(scores, codes=converging),
              "controller6_diverges_on_system_I")]
    for changed, name in cases:
        assert not headline_findings(changed, exact)[name]["reproduced"], name
    # runs that never settle count as infinitely slow: here controllers 1-4 are the slow ones
    assert headline_findings(unsettled, exact)["time_varying_slow"]["reproduced"] is False


def test_the_report_counts_zero_crossings_in_singular_and_plural():
    """The report's reason for a 'G' says "1 zero crossing" and "2 zero crossings"."""
    why = lambda n: _WHY["G"].format(tc=3.2, cr=_count(n, "zero crossing"))
    assert why(1) == ("it settles at t_c = 3.2 s but with 1 zero crossing of a coordinate or "
                      "large peak inputs (so not E)")
    assert "with 0 zero crossings of" in why(0) and "with 2 zero crossings of" in why(2)
