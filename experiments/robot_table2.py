"""Report Table 2 and Figs. 4-5: the unicycle controllers on the Khepera plant.

Runs the robot section of `vehsim reproduce` (Monte-Carlo grid of 8 controllers x 2 systems
x 4 missions x seeds in one jitted call, scored into E/G/S/C/O/U) and writes `report.md`,
`results.json` and the figures into the output folder.

Usage: PYTHONPATH=. python experiments/robot_table2.py [--full] [--out results/robot]
(quick: 4 seeds per cell, about a minute; full: 100 seeds per cell.)
"""

from __future__ import annotations

import argparse

import jax


jax.config.update("jax_enable_x64", True)


def main(argv=None) -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--full", action="store_true", help="100 seeds per cell (default: 4)")
    ap.add_argument("--out", default="results/robot")
    args = ap.parse_args(argv)
    from vehsim.reproduce import run

    run(args.out, quick=not args.full, only=["vehsim.robot"])


if __name__ == "__main__":
    main()
