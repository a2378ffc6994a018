r"""Progress on long work: host callbacks from inside compiled loops, shown on stderr.

Compiled code reports its progress with `advance` (after each chunk of sweep members or
each block of robot samples) or `reach` (each Levenberg-Marquardt step): a
`jax.debug.callback` that runs on the host once the work before it is done and moves the
innermost open `ProgressBar` (see `progress_bar`). A bar redraws at most every
`min_interval` seconds: one line rewritten in place on a terminal, a new line every 10 %
otherwise (log files of batch jobs). Without an open bar the callbacks do nothing.

The callbacks are compiled in only where progress is asked for: the batched functions
(`vehsim.sweep`, `vehsim.simulate_robot_grid`, the fits) take ``progress=None``, which
means the default set by `set_default`: off in the library, on in the command line
(``vehsim --no-progress ...`` turns it off). One callback per chunk of work costs little
against the chunk's work (docs/performance.md).

For a single `vehsim.simulate`, or your own ``jax.vmap(simulate)``, diffrax's progress
meters work under `vmap` (they follow the slowest member):
``simulate(..., progress_meter=diffrax.TextProgressMeter())``.
"""

from __future__ import annotations

import contextlib
import math
import sys
import threading
import time
from collections.abc import Iterator
from typing import TextIO

import jax
import jax.numpy as jnp
import numpy as np


_DEFAULT = [False]
_OPEN: list[ProgressBar] = []
_LOCK = threading.Lock()


def set_default(enabled: bool) -> bool:
    """Whether functions called with ``progress=None`` show progress (library: False; the
    command line sets True while it runs). Returns the previous default."""
    previous, _DEFAULT[0] = _DEFAULT[0], bool(enabled)
    return previous


def resolve(progress: bool | None) -> bool:
    """`progress`, or the default of `set_default` when it is None."""
    return _DEFAULT[0] if progress is None else bool(progress)


class ProgressBar:
    """A host-side progress line: ``label: 37% (380/1024 members), 4.1 s, ~7.0 s left``.

    **Arguments:** `label`, `total` (the work, in `unit`), `stream` (default stderr),
    `min_interval` [s] between redraws on a terminal, `value_name` (if given, the least
    value reported is shown under this name, e.g. a loss), `eta` (show the time left).
    """

    def __init__(self, label: str, total: float, unit: str = "", stream: TextIO | None = None,
                 min_interval: float = 0.5, value_name: str = "", eta: bool = True):
        self.label, self.total, self.unit, self.value_name = label, float(total), unit, value_name
        self.eta = eta
        self.stream = sys.stderr if stream is None else stream
        self.min_interval = min_interval
        self.done, self.value = 0.0, math.inf
        self.start = self._drawn = time.perf_counter()
        self._first: tuple[float, float] | None = None  # (time, done) at the first report
        self._tty = bool(getattr(self.stream, "isatty", lambda: False)())
        self._decile = 0
        self._shown = -1.0

    def advance(self, amount: float) -> None:
        """Count `amount` more units of work as done."""
        self.reach(self.done + amount)

    def reach(self, position: float, value: float = math.inf) -> None:
        """Count the work up to `position` as done; track the least `value` (e.g. a loss)."""
        with _LOCK:
            now = time.perf_counter()
            self.done = min(max(self.done, float(position)), self.total)
            self.value = min(self.value, float(value))
            if self._first is None:  # the rate is measured from here: compilation excluded
                self._first = (now, self.done)
            decile = int(10 * self.done / self.total) if self.total else 10
            if self._tty and now - self._drawn >= self.min_interval:
                self._draw(now, end="\r")
            elif not self._tty and decile > self._decile:
                self._draw(now, end="\n")
            self._decile = max(self._decile, decile)

    def close(self) -> None:
        """Draw the final line (unless the last line drawn already says it all)."""
        with _LOCK:
            if self._tty or self._shown != self.done:
                self._draw(time.perf_counter(), end="\n", last=True)

    def line(self, now: float | None = None, last: bool = False) -> str:
        """The text of the progress line: the time since the bar opened (compilation
        included) and the time left at the rate since the first report."""
        now = time.perf_counter() if now is None else now
        frac = self.done / self.total if self.total else 1.0
        unit = f" {self.unit}" if self.unit else ""
        text = f"{self.label}: {100 * frac:.0f}% ({self.done:.0f}/{self.total:.0f}{unit}), " \
               f"{now - self.start:.1f} s"
        if self.eta and self._first is not None and 0 < frac < 1 and not last:
            t1, d1 = self._first
            if self.done > d1 and now > t1:
                text += f", ~{(now - t1) / (self.done - d1) * (self.total - self.done):.1f} s left"
        if self.value_name and math.isfinite(self.value):
            text += f", {self.value_name} {self.value:.4g}"
        return text

    def _draw(self, now, end, last=False):
        self._drawn, self._shown = now, self.done
        print(self.line(now, last).ljust(78 if self._tty else 0), end=end, file=self.stream,
              flush=True)


@contextlib.contextmanager
def progress_bar(label: str, total: float, unit: str = "", enabled: bool = True,
                 **kwargs) -> Iterator[ProgressBar | None]:
    """Open a `ProgressBar` for the callbacks of the compiled work run inside the block
    (block until that work is done before leaving it); does nothing if not `enabled`. On
    leaving, the callbacks still in flight are waited for (`jax.effects_barrier`: a host
    callback may arrive after the arrays it reports on are ready), so the bar's last line
    counts all the work."""
    if not enabled:
        yield None
        return
    bar = ProgressBar(label, total, unit, **kwargs)
    _OPEN.append(bar)
    try:
        yield bar
    finally:
        jax.effects_barrier()
        _OPEN.remove(bar)
        bar.close()


def _host_advance(amount, after) -> None:
    del after
    if _OPEN:
        _OPEN[-1].advance(float(np.asarray(amount)))


def _host_reach(position, value) -> None:
    if _OPEN:
        _OPEN[-1].reach(float(np.max(position)), float(np.min(value)))


def _scalar(tree):
    """One element of the first array of `tree`: a cheap data dependence on its work."""
    leaves = [x for x in jax.tree.leaves(tree) if isinstance(x, jax.Array) and x.size]
    return jnp.ravel(leaves[0])[0] if leaves else jnp.zeros(())


def advance(amount, after):
    """Traced: when `after` (a PyTree of results) is computed, add `amount` to the open
    bar. Returns `after` unchanged."""
    jax.debug.callback(_host_advance, amount, _scalar(after))
    return after


def reach(position, value=jnp.inf) -> None:
    """Traced: the work has reached `position` (e.g. an iteration count), with `value`
    (e.g. a loss; the bar shows the least seen)."""
    jax.debug.callback(_host_reach, position, value)


__all__ = ["ProgressBar", "advance", "progress_bar", "reach", "resolve", "set_default"]
