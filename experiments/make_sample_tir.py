"""Make vehsim/data/tires/sample_185_80R14_mf61.tir, the MF 6.1 tyre property file vehsim ships.

Its coefficients are those of Project Chrono's PAC2002 (MF 5.2) file
``data/vehicle/VW_microbus/json/mf_185_80R14.tir`` (BSD-3-Clause, Chrono Development Team),
laid out as an MF 6.1 file (FITTYP = 61):

- every coefficient the two versions share is copied unchanged;
- MF 5.2's camber shift ``PHY3`` becomes MF 6.1's camber stiffness: ``PKY6 + PKY7 dfz`` is
  the per-load camber stiffness ``PHY3 K_ya0 / Fz + PVY3 + PVY4 dfz`` of the 5.2 file at the
  nominal load (value and slope in dfz), so F_y under camber matches the 5.2 file there;
- ``QSY7 = 1`` keeps M_y proportional to the load, as MF 5.2's rolling resistance is;
- the MF 6.1 terms the source has no data for are neutral (pressure terms 0, PKY4 = 2,
  PKY5 = PEY5 = QDZ10 = QDZ11 = RBX3 = RBY4 = 0, QSX4..QSX14 = 0), and the pressure range
  is our own choice around the source's 1.9 bar.

Usage: ``python experiments/make_sample_tir.py PATH/TO/mf_185_80R14.tir`` (writes the file
and prints where).
"""

from __future__ import annotations

import argparse
import math
from pathlib import Path

from vehsim._io import write_atomic
from vehsim.tire.tir import read_tir


OUT = Path(__file__).resolve().parent.parent / "vehsim" / "data" / "tires" / \
    "sample_185_80R14_mf61.tir"

HEADER = """\
! vehsim sample tyre property file: MF 6.1, 185/80 R14, 1.9 bar, nominal load 3800 N.
!
! Made by vehsim (experiments/make_sample_tir.py) from the PAC2002 (MF 5.2) file
! data/vehicle/VW_microbus/json/mf_185_80R14.tir of Project Chrono
! (https://projectchrono.org), whose coefficients are used here unchanged where MF 5.2 and
! MF 6.1 share them. The MF 6.1 camber stiffness PKY6, PKY7 reproduces the source's PHY3,
! PVY3, PVY4 camber terms at the nominal load; QSY7 = 1 keeps M_y proportional to the
! load; pressure terms are zero (the source has none) and the pressure range is ours.
! See docs/parameters.md.
!
! The source file is distributed under the BSD 3-Clause licence:
!
!   Copyright (c) 2013, Chrono Development Team. All rights reserved.
!   Redistribution and use in source and binary forms, with or without modification, are
!   permitted provided that the following conditions are met:
!   - Redistributions of source code must retain the above copyright notice, this list of
!     conditions and the following disclaimer.
!   - Redistributions in binary form must reproduce the above copyright notice, this list
!     of conditions and the following disclaimer in the documentation and/or other
!     materials provided with the distribution.
!   - Neither the name of the nor the names of its contributors may be used to endorse or
!     promote products derived from this software without specific prior written
!     permission.
!   THIS SOFTWARE IS PROVIDED BY THE COPYRIGHT HOLDERS AND CONTRIBUTORS "AS IS" AND ANY
!   EXPRESS OR IMPLIED WARRANTIES, INCLUDING, BUT NOT LIMITED TO, THE IMPLIED WARRANTIES OF
!   MERCHANTABILITY AND FITNESS FOR A PARTICULAR PURPOSE ARE DISCLAIMED. IN NO EVENT SHALL
!   THE COPYRIGHT HOLDER OR CONTRIBUTORS BE LIABLE FOR ANY DIRECT, INDIRECT, INCIDENTAL,
!   SPECIAL, EXEMPLARY, OR CONSEQUENTIAL DAMAGES (INCLUDING, BUT NOT LIMITED TO,
!   PROCUREMENT OF SUBSTITUTE GOODS OR SERVICES; LOSS OF USE, DATA, OR PROFITS; OR
!   BUSINESS INTERRUPTION) HOWEVER CAUSED AND ON ANY THEORY OF LIABILITY, WHETHER IN
!   CONTRACT, STRICT LIABILITY, OR TORT (INCLUDING NEGLIGENCE OR OTHERWISE) ARISING IN ANY
!   WAY OUT OF THE USE OF THIS SOFTWARE, EVEN IF ADVISED OF THE POSSIBILITY OF SUCH DAMAGE.
!
! Axes: ISO-W (TYDEX W), as MF-Tyre. Units: SI.
"""

LAYOUT = [
    ("MDI_HEADER", [("FILE_TYPE", "'tir'"), ("FILE_VERSION", "3.0"),
                    ("FILE_FORMAT", "'ASCII'")]),
    ("UNITS", [("LENGTH", "'meter'"), ("FORCE", "'newton'"), ("ANGLE", "'radians'"),
               ("MASS", "'kg'"), ("TIME", "'second'")]),
    ("MODEL", [("FITTYP", "61"), ("PROPERTY_FILE_FORMAT", "'USER'"), ("TYRESIDE", "'LEFT'"),
               ("LONGVL", None), ("VXLOW", None)]),
    ("DIMENSION", ["UNLOADED_RADIUS", "WIDTH", "ASPECT_RATIO", "RIM_RADIUS", "RIM_WIDTH"]),
    ("OPERATING_CONDITIONS", [("INFLPRES", "190000"), ("NOMPRES", "190000")]),
    ("VERTICAL", ["FNOMIN", "VERTICAL_STIFFNESS", "VERTICAL_DAMPING", "BREFF", "DREFF",
                  "FREFF"]),
    ("INFLATION_PRESSURE_RANGE", [("PRESMIN", "150000"), ("PRESMAX", "250000")]),
    ("VERTICAL_FORCE_RANGE", ["FZMIN", "FZMAX"]),
    ("LONG_SLIP_RANGE", ["KPUMIN", "KPUMAX"]),
    ("SLIP_ANGLE_RANGE", ["ALPMIN", "ALPMAX"]),
    ("INCLINATION_ANGLE_RANGE", ["CAMMIN", "CAMMAX"]),
    ("SCALING_COEFFICIENTS", [(k, "1") for k in (
        "LFZO LCX LMUX LEX LKX LHX LVX LCY LMUY LEY LKY LHY LVY LKYC LKZC LTR LRES LXAL LYKA "
        "LVYKA LS LSGKP LSGAL LMX LVMX LMY").split()]),
    ("LONGITUDINAL_COEFFICIENTS", [
        "PCX1", "PDX1", "PDX2", "PDX3", "PEX1", "PEX2", "PEX3", "PEX4", "PKX1", "PKX2", "PKX3",
        "PHX1", "PHX2", "PVX1", "PVX2", ("PPX1", "0"), ("PPX2", "0"), ("PPX3", "0"),
        ("PPX4", "0"), "RBX1", "RBX2", ("RBX3", "0"), "RCX1", "REX1", "REX2", "RHX1", "PTX1",
        "PTX2", "PTX3"]),
    ("OVERTURNING_COEFFICIENTS", ["QSX1", "QSX2", "QSX3"]
     + [(f"QSX{i}", "0") for i in range(4, 15)] + [("PPMX1", "0")]),
    ("LATERAL_COEFFICIENTS", [
        "PCY1", "PDY1", "PDY2", "PDY3", "PEY1", "PEY2", "PEY3", "PEY4", ("PEY5", "0"), "PKY1",
        "PKY2", "PKY3", ("PKY4", "2"), ("PKY5", "0"), ("PKY6", None), ("PKY7", None), "PHY1",
        "PHY2", "PVY1", "PVY2", "PVY3", "PVY4", ("PPY1", "0"), ("PPY2", "0"), ("PPY3", "0"),
        ("PPY4", "0"), ("PPY5", "0"), "RBY1", "RBY2", "RBY3", ("RBY4", "0"), "RCY1", "REY1",
        "REY2", "RHY1", "RHY2", "RVY1", "RVY2", "RVY3", "RVY4", "RVY5", "RVY6", "PTY1",
        "PTY2"]),
    ("ROLLING_COEFFICIENTS", ["QSY1", "QSY2", "QSY3", "QSY4", ("QSY5", "0"), ("QSY6", "0"),
                              ("QSY7", "1"), ("QSY8", "0")]),
    ("ALIGNING_COEFFICIENTS", [
        "QBZ1", "QBZ2", "QBZ3", "QBZ4", "QBZ5", "QBZ9", "QBZ10", "QCZ1", "QDZ1", "QDZ2", "QDZ3",
        "QDZ4", "QDZ6", "QDZ7", "QDZ8", "QDZ9", ("QDZ10", "0"), ("QDZ11", "0"), "QEZ1", "QEZ2",
        "QEZ3", "QEZ4", "QEZ5", "QHZ1", "QHZ2", "QHZ3", "QHZ4", ("PPZ1", "0"), ("PPZ2", "0"),
        "SSZ1", "SSZ2", "SSZ3", "SSZ4"]),
]


def camber_stiffness(src) -> tuple[float, float]:
    """(PKY6, PKY7): value and d/d(dfz) at dfz = 0 of the 5.2 file's camber stiffness per
    load, PHY3 * K_ya0 / Fz + PVY3 + PVY4 dfz, K_ya0 = PKY1 Fz0 sin(2 atan(Fz / (PKY2 Fz0)))."""
    pky1, pky2 = src.raw("PKY1"), src.raw("PKY2")
    phy3, pvy3, pvy4 = src.raw("PHY3", 0.0), src.raw("PVY3", 0.0), src.raw("PVY4", 0.0)

    def per_load(x):  # x = Fz / Fz0 = 1 + dfz
        return phy3 * pky1 * math.sin(2 * math.atan(x / pky2)) / x + pvy3 + pvy4 * (x - 1)

    h = 1e-6
    return per_load(1.0), (per_load(1 + h) - per_load(1 - h)) / (2 * h)


def make(src_path: str) -> str:
    src = read_tir(src_path)
    assert src.version == "5.2"
    pky6, pky7 = camber_stiffness(src)
    derived = {"PKY6": f"{pky6:.6g}", "PKY7": f"{pky7:.6g}"}
    lines = [HEADER.rstrip("\n")]
    for section, keys in LAYOUT:
        lines.append(f"${'-' * 60}{section.lower()}")
        lines.append(f"[{section}]")
        for item in keys:
            key, text = (item, None) if isinstance(item, str) else item
            if text is None:
                text = derived.get(key)
            if text is None:
                e = src.entry(key)
                text = e.text.split("=", 1)[1].split("$")[0].strip()
                comment = e.comment
            else:
                e = src.entry(key)
                comment = e.comment if e is not None else ""
            if key in derived:
                comment = "$camber stiffness from the source's PHY3, PVY3, PVY4"
            lines.append(f"{key:<24} = {text:<20} {comment}".rstrip())
    return "\n".join(lines) + "\n"


if __name__ == "__main__":
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("source", help="Project Chrono's mf_185_80R14.tir (PAC2002)")
    text = make(ap.parse_args().source)
    write_atomic(OUT, text)
    read_tir(OUT)  # it reads back
    print(OUT)
