"""Read real tyre property files and compare their summaries with what the files state.

For each file given: the formula version, the unknown keys, and `vehsim.mf_summary` at the
scaled nominal load (peak mu_x driving and braking, peak mu_y, the slips where they occur,
K_xk, K_ya) beside the values the files' own comments state for their coefficients
("PDX1: Longitudinal friction Mux at Fznom", "PDY1: Lateral friction Muy", "PKY1: Maximum
value of stiffness Kfy/Fznom" with PKY2, PKY4). One JSON line per file; files that vehsim
refuses print the refusal. The files are not shipped (see docs/tir.md for the sources).

Run: python experiments/tir_survey.py FILE.tir [FILE.tir ...]
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import jax

import vehsim as vs


jax.config.update("jax_enable_x64", True)


def survey(path: str) -> dict:
    try:
        tir = vs.read_tir(path)
    except vs.TirError as err:
        return {"file": Path(path).name, "refused": str(err)}
    params = vs.MFParams.from_tir(tir)
    s = vs.mf_summary(params)
    out = {"file": Path(path).name, "version": tir.version,
           "format": tir.raw("PROPERTY_FILE_FORMAT"), "fittyp": tir.raw("FITTYP"),
           "unknown_keys": [k for _, k, _ in tir.unknown_keys]}
    out.update({k: round(v, 4) if isinstance(v, float) else v for k, v in s.items()})
    out["mu_x_vs_stated"] = round(s["mu_x_drive"] / s["stated_mu_x"] - 1, 4)
    out["mu_y_vs_stated"] = round(s["mu_y"] / abs(s["stated_mu_y"]) - 1, 4)
    out["Kya_vs_stated"] = round(s["Kya"] / s["stated_Kya"] - 1, 6)
    return out


if __name__ == "__main__":
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("files", nargs="+", metavar="FILE.tir", help="tyre property files")
    for arg in ap.parse_args().files:
        print(json.dumps(survey(arg)), flush=True)
