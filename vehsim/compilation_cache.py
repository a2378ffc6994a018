r"""JAX's persistent compilation cache, switched on in one line for notebooks and scripts.

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
`default_cache_dir` or the folder JAX was already given (``JAX_COMPILATION_CACHE_DIR``);
``--no-compilation-cache`` or ``VEHSIM_NO_COMPILATION_CACHE=1`` turn it off.
"""

from __future__ import annotations

import os
from pathlib import Path

import jax


def default_cache_dir() -> Path:
    """``$VEHSIM_CACHE_DIR``, else ``$XDG_CACHE_HOME/vehsim/jax``, else
    ``~/.cache/vehsim/jax``."""
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
    path = Path(default_cache_dir() if path is None else path).expanduser().resolve()
    path.mkdir(parents=True, exist_ok=True)
    jax.config.update("jax_enable_compilation_cache", True)
    jax.config.update("jax_compilation_cache_dir", str(path))
    jax.config.update("jax_persistent_cache_min_compile_time_secs", float(min_compile_time))
    jax.config.update("jax_persistent_cache_min_entry_size_bytes", 0)
    return path


NO_CACHE_VARIABLE = "VEHSIM_NO_COMPILATION_CACHE"
"""Environment variable that turns the command line's compilation cache off (1, true, yes)."""


def command_line_cache(disabled: bool = False) -> Path | None:
    """The command line's cache: off if `disabled` or ``$VEHSIM_NO_COMPILATION_CACHE`` is
    1/true/yes (JAX's cache then switched off altogether, whatever else configured it),
    else `enable_compilation_cache` in the folder JAX was given, or `default_cache_dir`.

    **Returns:** the cache folder, or None when off.
    """
    if disabled or os.environ.get(NO_CACHE_VARIABLE, "").strip().lower() in ("1", "true", "yes"):
        jax.config.update("jax_enable_compilation_cache", False)
        return None
    return enable_compilation_cache(jax.config.jax_compilation_cache_dir or None)
