"""The compilation layer (`vehsim._compilation`): `vehsim.enable_compilation_cache` makes a
program compiled once load from the cache folder in the next compilation (in a fresh
process, so the test process's settings are untouched); the command line switches it on, in
the folder it is given, never the user's own under the tests; exported programs."""

import os
import subprocess
import sys
from pathlib import Path

import pytest

from vehsim._compilation import default_cache_dir


ROOT = Path(__file__).parent.parent

SCRIPT = """
import io, logging, sys
import jax, jax.numpy as jnp
import vehsim as vs

log = io.StringIO()
logger = logging.getLogger("jax._src.compiler")
logger.addHandler(logging.StreamHandler(log))
logger.setLevel(logging.DEBUG)
print(vs.enable_compilation_cache(sys.argv[1], min_compile_time=0.0))
f = jax.jit(lambda x: jnp.sin(x) @ x.T)
first = f(jnp.ones((3, 3)))
jax.clear_caches()  # forget the compiled program in memory: the next call compiles again
second = f(jnp.ones((3, 3)))
assert (first == second).all()
print("\\n".join(line for line in log.getvalue().splitlines() if "jit__lambda" in line))
"""


def test_a_program_compiled_once_is_loaded_from_the_cache(tmp_path):
    cache = tmp_path / "cache"
    out = subprocess.run([sys.executable, "-c", SCRIPT, str(cache)], capture_output=True,
                         text=True, env={"PYTHONPATH": str(ROOT), "PATH": ""}, timeout=300)
    assert out.returncode == 0, out.stderr
    path, log = out.stdout.split("\n", 1)
    assert Path(path) == cache.resolve()
    miss, hit = log.find("MISS for 'jit__lambda'"), log.find("cache hit for 'jit__lambda'")
    assert 0 <= miss < hit, log  # compiled and written, then read back
    assert any(p.name.startswith("jit__lambda") for p in cache.iterdir())


def test_default_cache_folder(monkeypatch, tmp_path):
    monkeypatch.setenv("VEHSIM_CACHE_DIR", str(tmp_path / "a"))
    assert default_cache_dir() == tmp_path / "a"
    monkeypatch.delenv("VEHSIM_CACHE_DIR")
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "xdg"))
    assert default_cache_dir() == tmp_path / "xdg" / "vehsim" / "jax"


def test_a_command_under_the_tests_leaves_the_home_cache_alone(tmp_path):
    """A command-line run in the tests' environment (tests/conftest.py), even one that lost
    ``JAX_COMPILATION_CACHE_DIR``, writes its compiled programs to the run's cache folder,
    never under the user's home: with HOME a fresh folder, nothing appears in it."""
    home = tmp_path / "home"
    home.mkdir()
    env = {k: v for k, v in os.environ.items()
           if k not in ("JAX_COMPILATION_CACHE_DIR", "XDG_CACHE_HOME")}
    env |= {"HOME": str(home), "PYTHONPATH": str(ROOT), "MPLCONFIGDIR": str(tmp_path / "mpl")}
    out = subprocess.run([sys.executable, "-m", "vehsim", "brake", "--surface", "tarmac"],
                         capture_output=True, text=True, env=env, timeout=300)
    assert out.returncode == 2 and "unknown surface 'tarmac'" in out.stderr, out.stderr
    assert not list(home.rglob("*"))
    assert Path(os.environ["VEHSIM_CACHE_DIR"]).is_dir()  # where it went


def test_command_line_cache_follows_the_flag_and_the_environment(monkeypatch):
    import jax

    from vehsim._compilation import NO_CACHE_VARIABLE, command_line_cache

    configured = jax.config.jax_compilation_cache_dir  # the suite's cache folder
    try:
        monkeypatch.delenv(NO_CACHE_VARIABLE, raising=False)
        assert command_line_cache() == Path(configured).resolve()  # JAX's folder kept
        assert jax.config.jax_enable_compilation_cache
        monkeypatch.setenv(NO_CACHE_VARIABLE, "1")
        assert command_line_cache() is None
        assert not jax.config.jax_enable_compilation_cache
        monkeypatch.setenv(NO_CACHE_VARIABLE, "0")
        assert command_line_cache() is not None and jax.config.jax_enable_compilation_cache
        assert command_line_cache(disabled=True) is None
        monkeypatch.setenv(NO_CACHE_VARIABLE, " On ")
        assert command_line_cache() is None
        for word in ("off", "No", ""):
            monkeypatch.setenv(NO_CACHE_VARIABLE, word)
            assert command_line_cache() is not None
        monkeypatch.setenv(NO_CACHE_VARIABLE, "maybe")
        with pytest.raises(ValueError, match="VEHSIM_NO_COMPILATION_CACHE='maybe': expected 1, "
                                             "true, yes or on"):
            command_line_cache()
    finally:
        jax.config.update("jax_enable_compilation_cache", True)
        jax.config.update("jax_compilation_cache_dir", configured)


def test_a_program_with_a_host_callback_is_not_exported(monkeypatch, tmp_path):
    """`exported_call` of a function JAX cannot export (a host callback) computes it through
    JAX's own tracing, writes nothing and remembers not to try again; an exportable one is
    written once and returns the same values."""
    import jax
    import jax.numpy as jnp
    import numpy as np

    import vehsim._compilation as cc

    monkeypatch.setattr(cc, "_exported_folder", lambda: tmp_path)
    monkeypatch.setattr(cc, "_programs", {})
    seen = []

    @jax.jit
    def noisy(x):
        jax.debug.callback(lambda v: seen.append(float(v)), x.sum())
        return 2.0 * x

    assert np.allclose(cc.exported_call("noisy", noisy, (jnp.arange(3.0),)), [0.0, 2.0, 4.0])
    assert seen == [3.0] and not list(tmp_path.iterdir())
    assert list(cc._programs.values()) == [None]
    quiet = jax.jit(lambda x: {"y": jnp.sin(x)})
    out = cc.exported_call("quiet", quiet, (jnp.arange(3.0),))
    np.testing.assert_array_equal(np.asarray(out["y"]), np.sin(np.arange(3.0)))
    assert [p.name.split("-")[0] for p in tmp_path.iterdir()] == ["quiet"]


def test_a_program_damaged_inside_its_file_is_exported_again(monkeypatch, tmp_path):
    """A stored program whose wrapper reads but whose StableHLO does not (bytes flipped
    inside it) is exported again, not a failure of every later run."""
    import jax
    import jax.numpy as jnp
    import numpy as np

    import vehsim._compilation as cc

    monkeypatch.setattr(cc, "_exported_folder", lambda: tmp_path)
    f = jax.jit(lambda x, y: jnp.sin(x) * 2.0 + y)
    args = (jnp.linspace(0.0, 1.0, 5), jnp.ones(5))
    monkeypatch.setattr(cc, "_programs", {})
    cc.exported_program("damaged", f, args)
    (path,) = tmp_path.iterdir()
    good = path.read_bytes()
    mended = 0
    for at in range(len(good) // 8, len(good), len(good) // 8):
        bad = bytearray(good)
        bad[at:at + 8] = bytes(b ^ 0xFF for b in bad[at:at + 8])
        path.write_bytes(bytes(bad))
        readable = cc._load_exported(path) is not None  # the damage is past the wrapper
        monkeypatch.setattr(cc, "_programs", {})  # a new process: only the file remains
        out = cc.exported_program("damaged", f, args)(*args)
        np.testing.assert_allclose(np.asarray(out), np.sin(np.asarray(args[0])) * 2.0 + 1.0,
                                   rtol=1e-15)
        if readable and path.read_bytes() != bad:  # rewritten: the new file compiles
            cc._compile_exported(cc._load_exported(path), list(args))
            mended += 1
    assert mended >= 1


def test_every_library_that_traces_into_a_program_keys_it(monkeypatch):
    """A new version of diffrax, lineax or optimistix (as of JAX, jaxlib or equinox) is a
    new exported program: the fingerprint in its key changes."""
    import vehsim._compilation as comp

    fingerprint = comp._source_fingerprint.__wrapped__
    before = fingerprint()
    real = comp.importlib.metadata.version
    for name in ("jax", "jaxlib", "equinox", "diffrax", "lineax", "optimistix"):
        monkeypatch.setattr(comp.importlib.metadata, "version",
                            lambda n, name=name: real(n) + ".post1" if n == name else real(n))
        assert fingerprint() != before, name
        monkeypatch.setattr(comp.importlib.metadata, "version", real)
    assert fingerprint() == before
