"""A guard against a thread-pool deadlock of XLA's CPU runtime in jaxlib 0.10.

jaxlib 0.10's CPU runtime schedules independent operations of one program concurrently (its
"concurrency-optimised scheduler"). A program with two independent batched LAPACK calls,
for example ``jax.vmap`` of a function that solves two linear systems, can then wait forever
on a machine with few cores: each call runs on a worker of the intra-op thread pool and
waits for work it queued on the same pool (two cores: two workers, both waiting). The
distributed 2D tire's steady state (one solve per axis) is such a program.

`configure_xla_cpu` (what `import vehsim` calls) switches that scheduler off through
``XLA_FLAGS`` before JAX starts its CPU backend (it has no effect once the backend runs, and
none on GPUs). A user who sets ``--xla_cpu_enable_concurrency_optimized_scheduler`` in
``XLA_FLAGS`` keeps their choice, and ``VEHSIM_KEEP_XLA_FLAGS=1`` opts out altogether.
Other jaxlib versions are left alone: XLA refuses flags it does not know.

`prefer_fast_compilation` (the command line's choice, same rules) switches off the CPU
fusion emitters, which compile slower than the older code generator.
"""

import os
import sys


FLAG = "--xla_cpu_enable_concurrency_optimized_scheduler"


def _affected(version: str) -> bool:
    try:
        major, minor = (int(p) for p in version.split(".")[:2])
    except ValueError:
        return False
    return (major, minor) == (0, 10)


OPT_OUT_VARIABLE = "VEHSIM_KEEP_XLA_FLAGS"
"""Environment variable (1, true, yes) that stops `import vehsim` from touching ``XLA_FLAGS``."""


def configure_xla_cpu(environ=os.environ) -> tuple[str, ...]:
    """The one process-wide setting vehsim makes: on jaxlib 0.10, XLA's concurrency-optimised
    CPU scheduler is switched off (``--xla_cpu_enable_concurrency_optimized_scheduler=false``
    appended to ``XLA_FLAGS``), because it can deadlock a program with two independent
    batched LAPACK calls on a machine with few cores.

    `import vehsim` calls it once. Its scope:

    - only jaxlib 0.10.x (XLA refuses flags it does not know; other versions are untouched);
    - only the CPU backend, and only if JAX has not started that backend yet (XLA reads
      ``XLA_FLAGS`` once per process): import vehsim, or call this, before your first JAX
      computation;
    - a user's own setting of that flag in ``XLA_FLAGS`` is kept;
    - ``VEHSIM_KEEP_XLA_FLAGS=1`` in the environment switches it off altogether (then call
      this function yourself, with that variable unset, where you want the guard).

    It prints nothing and warns nothing.

    **Returns:** the flags it added (empty when none).
    """
    if environ.get(OPT_OUT_VARIABLE, "").strip().lower() in ("1", "true", "yes"):
        return ()
    return (f"{FLAG}=false",) if guard_cpu_scheduler(environ) else ()


def guard_cpu_scheduler(environ=os.environ) -> bool:
    """Add ``FLAG=false`` to ``XLA_FLAGS`` for the affected jaxlib; True if it was added."""
    return _switch_off(FLAG, environ)


FUSION_EMITTERS_FLAG = "--xla_cpu_use_fusion_emitters"


def prefer_fast_compilation(environ=os.environ) -> bool:
    """Switch XLA's CPU fusion emitters off (``FUSION_EMITTERS_FLAG=false`` in ``XLA_FLAGS``,
    jaxlib 0.10 only, a user's own setting kept); True if the flag was added.

    The command line does this before JAX starts: a command compiles the optimal-control
    solver once per machine and then runs it for a fraction of a second, and the older
    emitters compile it noticeably faster for code only a little slower
    (docs/performance.md). The library itself keeps XLA's default."""
    return _switch_off(FUSION_EMITTERS_FLAG, environ)


def _switch_off(flag: str, environ) -> bool:
    from importlib.metadata import PackageNotFoundError, version

    try:
        affected = _affected(version("jaxlib"))
    except PackageNotFoundError:
        return False
    flags = environ.get("XLA_FLAGS", "")
    if not affected or flag in flags:
        return False
    environ["XLA_FLAGS"] = f"{flags} {flag}=false".strip()
    return True


CPU_DEVICES_VARIABLE = "JAX_NUM_CPU_DEVICES"


def cpu_devices_error(environ=os.environ) -> str | None:
    """What is wrong with ``$JAX_NUM_CPU_DEVICES`` (the CPU devices JAX makes; ``vehsim
    optimise --help`` suggests setting it), if anything. JAX refuses a value that is not a
    whole number at its import, with a traceback; it reads a negative count as "not set", and
    takes 0, then fails to start its CPU backend at the first computation."""
    value = environ.get(CPU_DEVICES_VARIABLE)
    if value is None or value.strip() == "":
        return None
    try:
        count = int(value)
    except ValueError:
        count = 0
    if count != 0:
        return None
    return (f"{CPU_DEVICES_VARIABLE}={value!r}: must be a whole number >= 1 (the CPU devices "
            "JAX makes), or unset for one")


def refuse_unreadable_environment(environ=os.environ) -> None:
    """Before JAX is imported: a ``$JAX_NUM_CPU_DEVICES`` that is not a whole number, which
    JAX's own import would refuse with a traceback, is refused here with the variable named
    (`ValueError`). Under the ``vehsim`` program (its console script, or ``python -m
    vehsim``) the message goes to stderr as the command line's errors do, with exit status 2.
    A count of 0 passes here: the command line refuses it before its first computation."""
    value = environ.get(CPU_DEVICES_VARIABLE, "").strip()
    try:
        int(value or "1")
    except ValueError:
        problem = cpu_devices_error(environ)
        if _command_line():
            sys.stderr.write(f"vehsim: error: {problem}\n")
            raise SystemExit(2) from None
        raise ValueError(problem) from None


def _command_line() -> bool:
    """Whether this process is the ``vehsim`` program (its console script, or ``python -m
    vehsim``), importing the package before its own code runs."""
    name = os.path.basename(sys.argv[0]) if sys.argv else ""
    if name in ("vehsim", "vehsim.exe", "vehsim-script.py"):
        return True
    orig = list(getattr(sys, "orig_argv", []))
    return any(a == "-m" and b == "vehsim" for a, b in zip(orig, orig[1:]))
