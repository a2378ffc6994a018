r"""The compilation layer: JAX's persistent compilation cache, exported programs, and the
command line's arrangement of its work around compilation. The solvers and models never
import it: they are jitted functions of arrays and modules; this layer decides, from above,
where their compiled programs are kept and what runs while they compile.

Most of the first run of a vehsim notebook or script is XLA compiling the solvers (the
suite is compile-bound: docs/performance.md). With the cache on, compiled programs are
written to a folder and a later process that builds the same program (same function,
shapes, dtypes, devices, JAX version and flags) loads it instead of compiling it:

```python
import vehsim as vs

vs.enable_compilation_cache()  # before the first computation
```

JAX does not write programs that contain host callbacks, and equinox's runtime checks
(``eqx.error_if``, which diffrax's solves contain) are host callbacks by default: those
programs, the solvers among them, are compiled again in every process. Starting Python with
``EQX_ON_ERROR=nan`` in the environment makes the checks return NaN instead, and those
programs are cached too; a failed check then shows as NaN rather than an exception (the
``result`` of a ``throw=False`` solve still names the failure). The measured difference for
the second run of a notebook, both ways: docs/performance.md.

The command line (`vehsim ...`) switches the cache on by itself (`command_line_cache`), in
the folder JAX was given (``JAX_COMPILATION_CACHE_DIR``) or `default_cache_dir`;
``--no-compilation-cache`` or ``VEHSIM_NO_COMPILATION_CACHE=1`` turn it off. Nothing else in
vehsim writes to disk for compilation: without a call to `enable_compilation_cache` or a
command, no folder is chosen.

JAX's cache saves the compilation, not the tracing and lowering before it, which for the
interior-point solve of a maneuver takes longer than loading the compiled program. While the
cache is on, the command line also keeps the programs of its solver as exported programs
(`jax.export`, in the ``exported`` subfolder; `exported_program`): a later process loads
them and goes straight to the (cached) compilation. `primitive_and_bound` is the optimal
primitive as the command line runs it: the car's program compiles or loads on a thread
while the starting guesses, the point-mass bound and the record's programs are made on the
other.
"""

from __future__ import annotations

import contextlib
import dataclasses
import functools
import hashlib
import importlib.metadata
import operator
import os
import threading
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import equinox as eqx
import jax
import numpy as np

from ._checks import check_nonnegative, is_count
from ._io import write_atomic
from .optimal.ip import IPOptions, IPSolution
from .optimal.ip.solver import _solve, canonical_options, solution_tree, solve_arguments, solver_of
from .optimal.primitive import SUBSTEPS, Primitive, _nodes, _signals, _violation_arrays
from .optimal.primitives import (
    DEFAULT_STARTS,
    _check_objective,
    batched_starts,
    best_of_guesses,
    best_start,
    car_guesses,
    car_problem,
    point_mass_bound,
    primitive_options,
    rally_gravel_car,
    solve_starts,
    starts_batch_size,
)
from .optimal.roads import Road
from .optimal.shooting import NU, NX, ManeuverOCP


def default_cache_dir() -> Path:
    """The folder `enable_compilation_cache` and the command line use when given none:
    ``$VEHSIM_CACHE_DIR``, else ``$XDG_CACHE_HOME/vehsim/jax``, else ``~/.cache/vehsim/jax``
    (only computed here; nothing is created until the cache is switched on)."""
    if os.environ.get("VEHSIM_CACHE_DIR"):
        return Path(os.environ["VEHSIM_CACHE_DIR"])
    base = os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache"
    return Path(base) / "vehsim" / "jax"


def enable_compilation_cache(path: str | os.PathLike | None = None,
                             min_compile_time: float = 0.2) -> Path:
    r"""Switch on JAX's persistent compilation cache (``jax_compilation_cache_dir``).

    **Arguments:**

    - `path`: the cache folder (created if needed; default `default_cache_dir`). Several
      processes may share it; delete it to clear the cache.
    - `min_compile_time` [s]: only programs that took at least this long to compile are
      written (JAX's default is 1 s; vehsim's solvers compile in 0.2 s to a minute).

    Call it before the first computation of the process: JAX reads these settings when it
    compiles its first program.

    **Returns:** the cache folder.
    """
    check_nonnegative("enable_compilation_cache", "min_compile_time", min_compile_time)
    path = Path(default_cache_dir() if path is None else path).expanduser().resolve()
    path.mkdir(parents=True, exist_ok=True)
    jax.config.update("jax_enable_compilation_cache", True)
    jax.config.update("jax_compilation_cache_dir", str(path))
    jax.config.update("jax_persistent_cache_min_compile_time_secs", float(min_compile_time))
    jax.config.update("jax_persistent_cache_min_entry_size_bytes", 0)
    return path


CACHE_SETTINGS = ("jax_enable_compilation_cache", "jax_compilation_cache_dir",
                  "jax_persistent_cache_min_compile_time_secs",
                  "jax_persistent_cache_min_entry_size_bytes")
"""The JAX settings `enable_compilation_cache` and `command_line_cache` change."""


@contextlib.contextmanager
def cache_settings_restored():
    """Run the body, then put `CACHE_SETTINGS` back as they were: a command run in the
    same process as other work (`vehsim.cli.main` from a notebook or a test) leaves the
    caller's cache as it found it."""
    saved = {name: getattr(jax.config, name) for name in CACHE_SETTINGS}
    try:
        yield
    finally:
        for name, value in saved.items():
            if getattr(jax.config, name) != value:
                jax.config.update(name, value)


NO_CACHE_VARIABLE = "VEHSIM_NO_COMPILATION_CACHE"
"""Environment variable that turns the command line's compilation cache off (1, true, yes,
on; 0, false, no, off or empty leave it on; case ignored)."""

_TRUE_WORDS, _FALSE_WORDS = ("1", "true", "yes", "on"), ("", "0", "false", "no", "off")


def cache_switched_off_by_environment() -> bool:
    """Whether ``$VEHSIM_NO_COMPILATION_CACHE`` turns the cache off; a value that is neither
    yes nor no is refused (`ValueError` naming the variable and the words it takes)."""
    value = os.environ.get(NO_CACHE_VARIABLE, "")
    word = value.strip().lower()
    if word not in _TRUE_WORDS + _FALSE_WORDS:
        raise ValueError(f"{NO_CACHE_VARIABLE}={value!r}: expected 1, true, yes or on (cache "
                         "off), or 0, false, no, off or empty (cache on)")
    return word in _TRUE_WORDS


def command_line_cache(disabled: bool = False) -> Path | None:
    """The command line's cache: off if `disabled` or ``$VEHSIM_NO_COMPILATION_CACHE`` says
    so (`cache_switched_off_by_environment`; JAX's cache then switched off altogether, whatever else configured it),
    else `enable_compilation_cache` in the folder JAX was given, or `default_cache_dir`,
    for every program however quickly it compiled: a command's dozens of small programs
    (array operations outside the solvers, the solution record's) load from the cache in
    less time than they compile.

    **Returns:** the cache folder, or None when off.
    """
    if disabled or cache_switched_off_by_environment():
        jax.config.update("jax_enable_compilation_cache", False)
        return None
    return enable_compilation_cache(jax.config.jax_compilation_cache_dir or None,
                                    min_compile_time=0.0)


EXPORTED_FOLDER = "exported"
"""Subfolder of the compilation cache holding `exported_program`'s serialized programs."""

_TRACING_FLAGS = ("jax_enable_x64", "jax_default_matmul_precision", "jax_numpy_rank_promotion",
                  "jax_numpy_dtype_promotion")
"""JAX settings that change what a function traces to (part of an exported program's key)."""

_programs: dict[str, Callable] = {}
_programs_lock = threading.Lock()


def exported_call(name: str, fn: Callable, args: tuple, out_tree=None):
    """``fn(*args)``, through `exported_program` when it gives one, else ``fn`` itself (a
    jitted function: JAX's own tracing and cache)."""
    program = exported_program(name, fn, args, out_tree)
    return fn(*args) if program is None else program(*args)


def exported_program(name: str, fn: Callable, args: tuple, out_tree=None) -> Callable | None:
    r"""``fn`` compiled for arguments structured as ``args`` (their array values do not
    matter), through a program exported to the compilation cache, or None when JAX's
    persistent cache is off or the arguments cannot key a program on disk (tracers, static
    parts whose ``repr`` loses information, or classes from outside `FAITHFUL_MODULES`).

    The program is found by a hash of ``name``, the arguments' tree structure with its
    static fields, their shapes and dtypes, the backend and its device count, the JAX
    settings that change the
    traced program (float64, matmul precision, promotion rules), ``EQX_ON_ERROR``, the
    versions of `KEYED_LIBRARIES`, and the source of vehsim itself (a changed model or
    solver is a new program). A missing program is exported (`jax.export`: traced and lowered
    once, written atomically to ``<cache>/exported/``); a present one is deserialized,
    skipping the tracing and lowering, and JAX's cache then provides the compilation.

    **Arguments:** ``name`` of the program in the file names; ``fn`` (pure, arrays in and a
    pytree of arrays out); ``args``; ``out_tree``: the tree structure of ``fn``'s output
    when it holds other nodes than tuples, lists and dicts (the exported program then
    returns its leaves).

    **Returns:** ``call(*args)`` with ``args`` of the same structure (arrays placed elsewhere
    are moved to the program's device), or None (also when ``fn`` cannot be exported, e.g.
    it contains a host callback).
    """
    folder = _exported_folder()
    if folder is None:
        return None
    dynamic, static = eqx.partition(args, eqx.is_array)
    leaves, treedef = jax.tree.flatten(dynamic)
    if not all(isinstance(x, jax.Array | np.ndarray) and not isinstance(x, jax.core.Tracer)
               for x in leaves):
        return None
    material = "\n".join([
        name, _source_fingerprint(), str(treedef), repr(jax.tree.leaves(static)),
        repr([(x.shape, str(x.dtype)) for x in leaves]), jax.default_backend(),
        str(len(jax.devices())),
        *(str(getattr(jax.config, flag)) for flag in _TRACING_FLAGS),
        os.environ.get("EQX_ON_ERROR", ""),
    ])
    if "..." in material or " at 0x" in material or not _faithful(treedef):
        return None  # a lossy repr cannot key a program
    key = hashlib.sha256(material.encode()).hexdigest()[:32]
    with _programs_lock:
        if key in _programs:
            return _programs[key]
    path = folder / f"{name}-{key}.bin"
    exported = _load_exported(path)
    compiled = None
    if exported is not None:
        try:
            compiled = _compile_exported(exported, leaves)
        except Exception:  # damaged inside a readable wrapper: exported again below
            path.unlink(missing_ok=True)
    if compiled is None:
        def flat(*flat_leaves):
            out = fn(*eqx.combine(jax.tree.unflatten(treedef, flat_leaves), static))
            if out_tree is None:
                return out
            if jax.tree.structure(out) != out_tree:
                raise TypeError(f"{name}: the output's structure is not out_tree")
            return jax.tree.leaves(out)

        avals = [jax.ShapeDtypeStruct(x.shape, x.dtype) for x in leaves]
        try:
            exported = jax.export.export(jax.jit(flat))(*avals)
            data = bytes(exported.serialize())
        except Exception:  # not exportable (a host callback, say): JAX's tracing serves
            with _programs_lock:
                _programs[key] = None
            return None
        write_atomic(path, data)
        compiled = _compile_exported(exported, leaves)
    shardings = compiled.input_shardings[0]

    def call(*call_args):
        flat_leaves = [
            x if not isinstance(x, jax.Array) or x.sharding.is_equivalent_to(s, x.ndim)
            else jax.device_put(x, s)  # e.g. one member of a batch split over devices
            for x, s in zip(jax.tree.leaves(eqx.filter(call_args, eqx.is_array)), shardings)
        ]
        out = compiled(*flat_leaves)
        return out if out_tree is None else jax.tree.unflatten(out_tree, out)

    with _programs_lock:
        _programs[key] = call
    return call


FAITHFUL_MODULES = ("vehsim", "equinox", "jax", "builtins")
"""Packages whose pytree node types print their static fields in full (the key of an
exported program is made of those prints): another package's classes, a user's problem
among them, keep JAX's own tracing."""


def _faithful(treedef) -> bool:
    node = treedef.node_data()
    if node is not None and node[0].__module__.split(".")[0] not in FAITHFUL_MODULES:
        return False
    return all(_faithful(child) for child in treedef.children())


def _exported_folder() -> Path | None:
    if not (jax.config.jax_enable_compilation_cache and jax.config.jax_compilation_cache_dir):
        return None
    return Path(jax.config.jax_compilation_cache_dir) / EXPORTED_FOLDER


def _compile_exported(exported, leaves):
    """The exported program compiled for arguments like `leaves` (split over the devices it
    was exported for, the first ones)."""
    if exported.nr_devices > 1:  # split over devices (multi-start): the same devices
        mesh = jax.sharding.Mesh(np.array(jax.devices()[:exported.nr_devices]), ("devices",))
        replicated = jax.sharding.NamedSharding(mesh, jax.sharding.PartitionSpec())
        call_exported = jax.jit(exported.call, in_shardings=replicated)
    else:
        call_exported = jax.jit(exported.call)
    return call_exported.lower(*leaves).compile()


def _load_exported(path: Path):
    """The exported program at ``path``; None when absent or unreadable (a partial or foreign
    file is exported again)."""
    try:
        return jax.export.deserialize(bytearray(path.read_bytes()))
    except Exception:  # absent, truncated or from another serialization version
        return None


KEYED_LIBRARIES = ("jax", "jaxlib", "equinox", "diffrax", "lineax", "optimistix")
"""The libraries whose versions key an exported program: those that trace into it."""


def _library_versions() -> dict[str, str]:
    return {name: importlib.metadata.version(name) for name in KEYED_LIBRARIES}


@functools.cache
def _source_fingerprint() -> str:
    """Hash of the library versions (`KEYED_LIBRARIES`) and every source file of vehsim."""
    h = hashlib.sha256(repr(sorted(_library_versions().items())).encode())
    root = Path(__file__).resolve().parent
    for f in sorted(root.rglob("*.py")):
        h.update(str(f.relative_to(root)).encode())
        h.update(f.read_bytes())
    return h.hexdigest()


def exported_interior_point(prob, xs0, us0, options: IPOptions | None = None, *,
                            throw: bool = True) -> IPSolution:
    """`vehsim.interior_point` through its exported program (`exported_program`) where the
    persistent cache is on and the arguments are concrete, else `interior_point` itself:
    the same program, the same solution bit for bit."""
    program = lambda *a: exported_call("interior_point", _solve, a, solution_tree())
    return solver_of(program)(prob, xs0, us0, options, throw=throw)


def compiled_interior_point(prob, xs0, us0, options: IPOptions | None = None):
    """`vehsim.optimal.ip.compile_interior_point` through its exported program where the
    persistent cache is on (loaded, or exported and written): ``solve(prob, xs0, us0,
    options, *, throw=True)`` for arguments shaped as these."""
    options = IPOptions() if options is None else options
    args = solve_arguments(prob, xs0, us0, options)
    compiled = (exported_program("interior_point", _solve, args, solution_tree())
                or _solve.lower(*args).compile())
    return solver_of(compiled, options)


def compiled_starts(prob: ManeuverOCP, n_pad: int, options: IPOptions):
    """`vehsim.optimal.primitives.solve_starts` for ``n_pad`` starts, compiled ahead of time
    (through its exported program when the cache is on): ``solve(prob, xs0, us0,
    options)`` with ``options`` as `canonical_options` gives them."""
    batch = starts_batch_size()
    dtype = jax.numpy.result_type(float)
    args = (prob, np.zeros((n_pad, prob.num_stages + 1, NX), dtype),
            np.zeros((n_pad, prob.num_stages, NU), dtype), options)
    exported = exported_program(f"interior_point_starts_batch{batch}",
                                lambda *a: solve_starts(*a, batch), args, solution_tree())
    if exported is not None:
        return exported
    compiled = solve_starts.lower(*args, batch).compile()
    return lambda *a: compiled(*a, batch)


def prepare_record_programs(prob: ManeuverOCP, xs, us, substeps: int = SUBSTEPS) -> None:
    """Export or load (`exported_program`) the three programs that the record and the figure
    of a car primitive run through `exported_call` (a `Primitive` with that ``runner``), for
    a problem shaped as ``prob`` with knots and inputs shaped as ``xs``, ``us`` (their values
    do not matter: a starting guess will do), so that a caller can do it while it waits for
    something else. Nothing happens when the cache is off (the programs then compile when
    first run)."""
    nodes = np.zeros((prob.num_stages * prob.steps_per_stage + 1, np.shape(xs)[-1]),
                     np.asarray(xs).dtype)
    for name, fn, args in (("nodes", _nodes, (prob, xs, us)),
                           ("violations", _violation_arrays, (prob, xs, us, substeps)),
                           ("signals", _signals, (prob.vehicle, nodes))):
        exported_program(name, fn, args)


def primitive_and_bound(road: str | Road = "corner90", objective: str = "min-time", *,
                        car=None, tf_max: float = 4.0, num_stages: int = 50,
                        steps_per_stage: int = 3, options: IPOptions | None = None,
                        starts=DEFAULT_STARTS, throw: bool = True, corner_clearance: bool = True,
                        interior_points: int = 0) -> tuple[Primitive, Primitive]:
    """`vehsim.primitive_and_bound` (same arguments, same programs, same numbers) arranged
    for the time to the first answer: the car's program compiles, or loads
    (`compiled_interior_point`, `compiled_starts`), on a thread while this one makes the
    starting guesses, solves the point-mass bound (its program is the seeds', ready by then)
    and prepares the record's programs (`prepare_record_programs`); every point-mass solve
    goes through its exported program (`exported_interior_point`), and both primitives read
    their nodes, signals and violations through theirs (``runner=exported_call``). XLA
    releases Python's lock while it compiles or loads, so no extra wall time where that
    takes longer (a first run: seconds; a run from the compilation cache: a few tenths).

    **Returns:** ``(primitive, bound)``.
    """
    _check_objective(objective)
    car = rally_gravel_car() if car is None else car
    options = primitive_options(objective, starts) if options is None else options
    prob = car_problem(road, objective, car, num_stages, steps_per_stage, tf_max,
                       corner_clearance=corner_clearance, interior_points=interior_points)
    batched = is_count(starts)
    if batched:
        starts = operator.index(starts)
    with ThreadPoolExecutor(1) as pool:
        if batched:
            canonical, n_dev = canonical_options(options), len(jax.devices())
            pending = pool.submit(compiled_starts, prob, -(-starts // n_dev) * n_dev, canonical)
            xs0, us0 = batched_starts(prob, starts)
            first = (xs0[0], us0[0])
        else:
            pending = pool.submit(compiled_interior_point, prob,
                                  np.zeros((num_stages + 1, NX)), np.zeros((num_stages, NU)),
                                  options)  # shapes only
            guesses = car_guesses(prob, starts, solver=exported_interior_point)
            first = guesses[0]
        bound = point_mass_bound(road, objective, D=float(car.tire.D), num_stages=num_stages,
                                 steps_per_stage=steps_per_stage, tf_max=tf_max, throw=False,
                                 solver=exported_interior_point,
                                 corner_clearance=corner_clearance,
                                 interior_points=interior_points)
        prepare_record_programs(prob, *first)
        solve = pending.result()
    if batched:
        prim = best_start(prob, solve(prob, xs0, us0, canonical), starts, options.verbose, throw)
    else:
        prim = best_of_guesses(prob, guesses, options, solve, throw)
    return (dataclasses.replace(prim, runner=exported_call),
            dataclasses.replace(bound, runner=exported_call))
