"""The guard against jaxlib 0.10's CPU thread-pool deadlock (vehsim/_xla_cpu.py)."""

import os
import subprocess
import sys
from importlib.metadata import version
from pathlib import Path

import pytest

from vehsim._xla_cpu import (
    FLAG,
    FUSION_EMITTERS_FLAG,
    OPT_OUT_VARIABLE,
    _affected,
    configure_xla_cpu,
    guard_cpu_scheduler,
    prefer_fast_compilation,
)


ROOT = Path(__file__).resolve().parents[1]

# two independent batched LU solves in one program, run until a deadlock would have shown
# (without the guard it hangs within 200 calls on a two-core machine)
PROGRAM = """
import vehsim, jax, jax.numpy as jnp
jax.config.update("jax_enable_x64", True)
A = jnp.eye(49)[None] * (1.0 + jnp.arange(40.0))[:, None, None] + 0.01
b = jnp.ones((40, 49))
f = jax.jit(jax.vmap(lambda a, c: jnp.stack([jnp.linalg.solve(a, c),
                                            jnp.linalg.solve(2.0 * a, c)])))
for _ in range(400):
    x = f(A, b).block_until_ready()
print(float(x[0, 0, 0]), flush=True)
"""


def test_guard_adds_the_flag_for_the_affected_jaxlib_only_and_keeps_the_users_choice():
    assert _affected("0.10.2") and not _affected("0.9.2") and not _affected("0.11.0")
    env = {"XLA_FLAGS": "--xla_backend_optimization_level=0"}
    added = guard_cpu_scheduler(env)
    assert added == _affected(version("jaxlib"))
    if added:
        assert env["XLA_FLAGS"] == f"--xla_backend_optimization_level=0 {FLAG}=false"
    mine = {"XLA_FLAGS": f"{FLAG}=true"}
    assert not guard_cpu_scheduler(mine) and mine["XLA_FLAGS"] == f"{FLAG}=true"


def test_configure_xla_cpu_returns_what_it_added_keeps_the_user_s_setting_and_opts_out():
    """`configure_xla_cpu` (what `import vehsim` calls, `vehsim.configure_xla_cpu`): on
    jaxlib 0.10 it appends the scheduler flag (off) to the user's flags and returns it; a
    user's own setting of the flag is kept (nothing added), and ``VEHSIM_KEEP_XLA_FLAGS=1``
    leaves ``XLA_FLAGS`` alone; it warns nothing."""
    import warnings

    import vehsim

    assert vehsim.configure_xla_cpu is configure_xla_cpu
    affected = _affected(version("jaxlib"))
    env = {"XLA_FLAGS": "--xla_backend_optimization_level=0"}
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        added = configure_xla_cpu(env)
    assert added == ((f"{FLAG}=false",) if affected else ())
    assert env["XLA_FLAGS"] == " ".join(["--xla_backend_optimization_level=0", *added])
    assert configure_xla_cpu(env) == () and env["XLA_FLAGS"].count(FLAG) == int(affected)
    mine = {"XLA_FLAGS": f"{FLAG}=true"}
    assert configure_xla_cpu(mine) == () and mine["XLA_FLAGS"] == f"{FLAG}=true"
    for value in ("1", "true", "YES"):
        kept = {OPT_OUT_VARIABLE: value}
        assert configure_xla_cpu(kept) == () and "XLA_FLAGS" not in kept
    if affected:
        assert configure_xla_cpu({OPT_OUT_VARIABLE: "0"}) == (f"{FLAG}=false",)


def test_the_command_line_s_code_generator_flag_follows_the_same_rules():
    """`prefer_fast_compilation` adds the fusion-emitters flag (off) for jaxlib 0.10 only,
    after what the user has, and keeps a user's own setting; the test run has it, so that
    the command-line runs and the tests share their compiled programs."""
    env = {"XLA_FLAGS": "--xla_backend_optimization_level=0"}
    added = prefer_fast_compilation(env)
    assert added == _affected(version("jaxlib"))
    if added:
        assert env["XLA_FLAGS"] == (f"--xla_backend_optimization_level=0 "
                                    f"{FUSION_EMITTERS_FLAG}=false")
        assert f"{FUSION_EMITTERS_FLAG}=false" in os.environ["XLA_FLAGS"]
    mine = {"XLA_FLAGS": f"{FUSION_EMITTERS_FLAG}=true"}
    assert not prefer_fast_compilation(mine)
    assert mine["XLA_FLAGS"] == f"{FUSION_EMITTERS_FLAG}=true"


@pytest.mark.skipif(not _affected(version("jaxlib")), reason="only jaxlib 0.10 deadlocks")
def test_two_independent_batched_solves_finish_after_import_vehsim():
    flags = " ".join(f for f in os.environ.get("XLA_FLAGS", "").split() if FLAG not in f)
    env = dict(os.environ, PYTHONPATH=str(ROOT), XLA_FLAGS=flags)
    out = subprocess.run([sys.executable, "-c", PROGRAM], env=env, capture_output=True,
                         text=True, timeout=120)
    assert out.returncode == 0, out.stderr
    # (I + 0.01 * ones) x = ones  ->  x_i = 1 / (1 + 0.01 * 49)
    assert float(out.stdout) == pytest.approx(1.0 / 1.49, rel=1e-12)
