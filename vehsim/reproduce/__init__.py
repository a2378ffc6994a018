"""`vehsim reproduce`: regenerate the report's figures and tables into one folder.

Each part of the report contributes a *section*: a module of this package, listed in
`SECTIONS`, with a ``TITLE`` and a function ``reproduce(ctx)``. A section draws its figures with
`ReproduceContext.figure`, writes tables and text with `ReproduceContext.text`, and records
numbers with `ReproduceContext.record`; `run` writes ``report.md`` and ``results.json``.
"""

from __future__ import annotations

import dataclasses
import importlib
import sys
import time
from pathlib import Path
from typing import Any

from .._io import save_figure, write_atomic, write_json
from .._result_files import with_units


SECTIONS: tuple[str, ...] = (  # in the order of the report
    "vehsim.reproduce.robot",  # 2.1, Table 2, Figs. 4-5
    "vehsim.reproduce.longitudinal",  # 2.2, Fig. 7
    "vehsim.reproduce.identify",  # 2.2, Figs. 10-11
    "vehsim.reproduce.combined",  # 2.3-2.4, Figs. 13-15, 17
    "vehsim.reproduce.vehicle",  # 2.5, eqs. 49-63
    "vehsim.reproduce.optimal",  # 2.5, Table 4, Fig. 20
    "vehsim.reproduce.braking_control",  # 2.2, closing the loop: ABS, estimation
)


@dataclasses.dataclass
class ReproduceContext:
    """What a section gets: where to write, how much work to do, and the report to fill.
    ``tiny`` (implies ``quick``): the smallest sizes that still run every step, for the tests
    of the command line; its numbers are not results."""

    out: Path
    quick: bool
    tiny: bool = False
    lines: list[str] = dataclasses.field(default_factory=list)
    results: dict[str, Any] = dataclasses.field(default_factory=dict)

    def text(self, *lines: str) -> None:
        self.lines.extend(lines)
        self.lines.append("")

    def figure(self, fig, name: str, caption: str) -> Path:
        import matplotlib.pyplot as plt

        path = save_figure(fig, self.out / f"{name}.png")
        plt.close(fig)
        self.lines += [f"![{caption}]({name}.png)", "", f"*{caption}*", ""]
        self.log(f"wrote {path}")
        return path

    def record(self, key: str, value: Any) -> None:
        self.results[key] = value

    def log(self, message: str) -> None:
        print(f"  {message}", file=sys.stderr, flush=True)


def run(out: str | Path = "results", quick: bool = True, only: list[str] | None = None,
        tiny: bool = False) -> Path:
    """Run every section (or those whose name contains one of the words in `only`);
    ``tiny``: see `ReproduceContext`."""
    import matplotlib

    matplotlib.use("Agg")
    sections = [s for s in SECTIONS if not only or any(o in s.rsplit('.', 1)[1] for o in only)]
    if not sections:  # before anything is written
        raise ValueError(f"no section matches {only}; sections: "
                         f"{[s.rsplit('.', 1)[1] for s in SECTIONS]}")
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    ctx = ReproduceContext(out=out, quick=quick or tiny, tiny=tiny)
    mode = "tiny" if tiny else "quick" if quick else "full"
    ctx.text(
        "# vehsim reproduction report",
        f"Mode: {mode}. Equation, figure and table numbers refer to "
        "Tsiotras, *Analysis and Control of High-Speed Wheeled Mobile Robots*, final report, 2004.",
    )
    for i, name in enumerate(sections, 1):
        module = importlib.import_module(name)
        print(f"[{i}/{len(sections)}] {module.TITLE}", file=sys.stderr, flush=True)
        t0 = time.perf_counter()
        ctx.text(f"## {module.TITLE}")
        module.reproduce(ctx)
        ctx.record(f"{name}.wall_time_s", round(time.perf_counter() - t0, 2))
    write_atomic(out / "report.md", "\n".join(ctx.lines))
    write_json(out / "results.json", with_units(ctx.results, strict=False))
    print(f"report: {out / 'report.md'}", file=sys.stderr)
    return out / "report.md"
