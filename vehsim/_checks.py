"""Input validation shared by every parameter module.

Checks run at construction (``__check_init__``) on concrete values only: inside ``jit`` or
``vmap`` the fields are tracers and the checks are skipped, so validated presets can be
batched and differentiated freely.
"""

from __future__ import annotations

import dataclasses
import math
import operator

import jax
import numpy as np


def is_concrete(x) -> bool:
    """True when ``x`` holds concrete numbers: neither a tracer nor a container of one
    (a tuple of floats and a traced angle, say)."""
    return not any(isinstance(leaf, jax.core.Tracer) for leaf in jax.tree.leaves(x))


def is_numeric(x) -> bool:
    """False for text and truth values, scalars or arrays of them (a string, bytes, a bool,
    an array of strings or bools): NumPy reads ``"0.5"`` and ``True`` as numbers, a
    parameter must not."""
    if isinstance(x, str | bytes | bool | np.bool_):
        return False
    if isinstance(x, list | tuple):
        return all(is_numeric(e) for e in x)
    kind = getattr(getattr(x, "dtype", None), "kind", None)
    return not (isinstance(kind, str) and kind in "bUS")


def _values(x, label: str, kind: str = "a number") -> np.ndarray | None:
    """``x`` as a float array (None for a tracer); `label` names it and `kind` says what it
    must be in the error that refuses text or truth values."""
    if not is_numeric(x):
        shown = np.asarray(x).tolist() if is_concrete(x) else x
        raise ValueError(f"{label} must be {kind}, got {shown!r}")
    if not is_concrete(x):
        return None
    return np.asarray(x, dtype=float)


def plain(x) -> str:
    """Numbers as a person writes them: ``-5``, ``0.25``, ``[1, -1]`` (at most 8 values)."""
    v = np.asarray(x, dtype=float)
    if v.ndim == 0:
        return f"{float(v):g}"
    flat = [f"{float(e):g}" for e in v.ravel()[:8]]
    return "[" + ", ".join(flat) + (", ...]" if v.size > 8 else "]")


def check_finite(owner: str, name: str, x) -> None:
    """Raise ``ValueError`` if ``x`` has a NaN or inf."""
    v = _values(x, f"{owner}.{name}")
    if v is not None and not np.all(np.isfinite(v)):
        raise ValueError(f"{owner}.{name} must be finite, got {plain(v)}")


def check_not_nan(owner: str, name: str, x) -> None:
    """Raise ``ValueError`` if ``x`` has a NaN (an infinity is a value here)."""
    v = _values(x, f"{owner}.{name}")
    if v is not None and np.any(np.isnan(v)):
        raise ValueError(f"{owner}.{name} must be a number (or +-inf), got {plain(v)}")


def check_range(
    owner: str,
    name: str,
    x,
    *,
    lower: float = -math.inf,
    upper: float = math.inf,
    lower_open: bool = False,
    upper_open: bool = False,
    allow_inf: bool = False,
) -> None:
    """Raise ``ValueError`` naming the field and the allowed range if ``x`` is outside it;
    `allow_inf`: an infinite upper end of the range is a value (NaN is never one)."""
    v = _values(x, f"{owner}.{name}")
    if v is None:
        return
    if not allow_inf:
        check_finite(owner, name, x)
    lo_ok = np.all(v > lower) if lower_open else np.all(v >= lower)
    hi_ok = np.all(v < upper) if upper_open else np.all(v <= upper)
    if not (lo_ok and hi_ok):
        lb = "(" if lower_open or lower == -math.inf else "["
        ub = ")" if upper_open or (upper == math.inf and not allow_inf) else "]"
        raise ValueError(
            f"{owner}.{name} must lie in {lb}{lower:g}, {upper:g}{ub}, got {plain(v)}"
        )


def check_positive(owner: str, name: str, x) -> None:
    check_range(owner, name, x, lower=0.0, lower_open=True)


def check_nonnegative(owner: str, name: str, x) -> None:
    check_range(owner, name, x, lower=0.0)


def check_integer(owner: str, name: str, x, *, lower: int = 0) -> None:
    """Raise ``ValueError`` unless ``x`` is a whole number >= `lower` (a concrete one)."""
    v = _values(x, f"{owner}.{name}", f"an integer >= {lower}")
    if v is None:
        return
    if not (np.all(np.isfinite(v)) and np.all(v == np.round(v)) and np.all(v >= lower)):
        raise ValueError(f"{owner}.{name} must be an integer >= {lower}, got {plain(v)}")


def is_count(value) -> bool:
    """True for an integer of any kind that `operator.index` takes (Python, NumPy, 0-d JAX),
    not a bool: what a count such as a number of starts may be, as against a sequence."""
    if isinstance(value, bool):
        return False
    try:
        operator.index(value)
    except TypeError:
        return False
    return True


def check_count(owner: str, name: str, value, *, lower: int = 1, sep: str = ".") -> None:
    """Raise ``ValueError`` unless `value` is an integer >= `lower` (a Python, NumPy or 0-d
    JAX integer; not a bool): a static count (steps, iterations, stages) that sizes a
    program."""
    if not is_count(value) or operator.index(value) < lower:
        raise ValueError(f"{owner}{sep}{name} must be an integer >= {lower}, got {value!r}")


def check_shaped_like(owner: str, name: str, given, reference, what: str) -> None:
    """Raise ``ValueError`` unless the PyTree `given` has the structure and leaf shapes of
    `reference` (`what` says where the reference comes from, e.g. ``LumpedLuGre.init_state()``)."""
    if jax.tree.structure(given) != jax.tree.structure(reference) or any(
            np.shape(a) != np.shape(b) for a, b in zip(jax.tree.leaves(given),
                                                       jax.tree.leaves(reference))):
        raise ValueError(f"{owner}: {name} must be shaped as {what}, "
                         f"{jax.tree.map(np.shape, reference)}, got "
                         f"{jax.tree.map(np.shape, given)}")


def check_type(owner: str, name: str, value, kind: type, *, optional: bool = False) -> None:
    """Raise ``TypeError`` unless `value` is a `kind` (or None, where `optional`): a model
    of the wrong kind fails at once, naming the field, not deep inside a solve."""
    if not (isinstance(value, kind) or (optional and value is None)):
        article = "an" if kind.__name__[0] in "AEIOU" else "a"
        raise TypeError(f"{owner}.{name} must be {article} {kind.__name__}"
                        f"{' or None' if optional else ''}, got {type(value).__name__}")


def check_order(owner: str, small: str, x_small, big: str, x_big) -> None:
    """Raise ``ValueError`` unless ``x_small <= x_big`` (e.g. mu_c <= mu_s)."""
    a, b = _values(x_small, f"{owner}.{small}"), _values(x_big, f"{owner}.{big}")
    if a is None or b is None:
        return
    if not np.all(a <= b):
        raise ValueError(f"{owner} needs {small} <= {big}, got {small} = {plain(a)}, "
                         f"{big} = {plain(b)}")


def check_times(owner: str, ts) -> None:
    """Raise ``ValueError`` unless concrete save times ``ts`` are a non-empty 1-D array,
    finite and non-decreasing (a solve runs from ``ts[0]`` to ``ts[-1]``)."""
    v = _values(ts, f"{owner}: ts")
    if v is None:
        return
    if v.ndim != 1 or v.size == 0:
        raise ValueError(f"{owner}: ts must be a non-empty 1-D array of times [s], got shape "
                         f"{v.shape}")
    if not np.all(np.isfinite(v)):
        i = int(np.argmin(np.isfinite(v)))
        raise ValueError(f"{owner}: ts must be finite, got {v[i]:g} at index {i}")
    back = np.diff(v) < 0
    if np.any(back):
        i = int(np.argmax(back)) + 1
        raise ValueError(f"{owner}: ts must be increasing, got {v[i]:g} after {v[i - 1]:g} "
                         f"(index {i})")


def check_finite_signals(owner: str, **signals) -> None:
    """Raise ``ValueError`` naming the first concrete signal (a constant or samples; a
    callable or a tracer is not looked at) with a NaN or inf: a solve would otherwise
    spend its step budget and report that it ran out of steps."""
    for name, x in signals.items():
        if x is None or callable(x) or not is_concrete(x):
            continue
        try:
            v = np.asarray(x, dtype=float)
        except (TypeError, ValueError):
            continue
        if not np.all(np.isfinite(v)):
            bad = v[~np.isfinite(v)].ravel()[0]
            raise ValueError(f"{owner}: {name} must be finite, got {bad:g}")


MAX_SAMPLES = 1_000_000
"""The most control samples `sample_count` allows a simulation: the loops keep every
sample's signals in memory (a braking's at 1 ms: 1000 s)."""


def sample_count(owner: str, duration, sample_time, substeps=1) -> int:
    """The number of whole samples of ``sample_time`` in ``duration`` [s], at least 1 and at
    most `MAX_SAMPLES`; raises ``ValueError`` naming `duration` (finite, > 0) or `substeps`
    (an integer >= 1)."""
    d = float(duration)
    if not (math.isfinite(d) and d > 0):
        raise ValueError(f"{owner}: duration [s] must lie in (0, inf), got {d:g}")
    T = float(sample_time)
    n = round(d / T)
    if n < 1:
        raise ValueError(f"{owner}: duration ({d:g} s) must be at least half a sample "
                         f"({T:g} s)")
    if n > MAX_SAMPLES:
        raise ValueError(f"{owner}: duration ({d:g} s) is {n:.3g} samples of {T:g} s; at most "
                         f"{MAX_SAMPLES:,} are simulated in one call (every sample's signals "
                         f"are kept): at most {MAX_SAMPLES * T:g} s")
    if isinstance(substeps, bool) or not float(substeps).is_integer() or substeps < 1:
        raise ValueError(f"{owner}: substeps must be an integer >= 1, got {substeps!r}")
    return n


def require_float64(what: str, why: str) -> None:
    """Raise ``ValueError`` unless JAX runs in float64 (``jax_enable_x64``): `what` needs
    it, and `why` says what float32 does to it."""
    if not jax.config.jax_enable_x64:
        raise ValueError(f"{what} needs float64: call jax.config.update('jax_enable_x64', "
                         f"True) first. {why}")


def recheck_modules(tree) -> None:
    """Run the construction checks (``__check_init__``) of every `eqx.Module` in `tree`, its
    submodules first: a model edited with `eqx.tree_at`, which builds no new module and so
    runs none of them, meets the checks its values would meet in its constructor (the
    concrete ones; traced values are not looked at, as in the constructors)."""
    import equinox as eqx

    seen = set()

    def visit(x):
        if isinstance(x, eqx.Module):
            if id(x) in seen:
                return
            seen.add(id(x))
            for f in dataclasses.fields(x):
                visit(getattr(x, f.name, None))
            for cls in reversed(type(x).__mro__):
                check = cls.__dict__.get("__check_init__")
                if check is not None:
                    check(x)
        elif isinstance(x, list | tuple):
            for y in x:
                visit(y)
        elif isinstance(x, dict):
            for y in x.values():
                visit(y)

    visit(tree)
