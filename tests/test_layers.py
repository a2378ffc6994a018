"""The package's layers only point down.

Model packages compute; the drawing (`vehsim.plot`), the report sections (`vehsim.reproduce`)
and the command line (`vehsim.cli`) sit on top of them. Read from the source (every import
statement, module level or inside functions): no model module imports an upper layer, the
upper layers import each other only downwards, and the packages have no import cycle.
"""

import ast
from pathlib import Path

import pytest


ROOT = Path(__file__).parent.parent / "vehsim"
UPPER = ("plot", "reproduce", "cli")  # bottom to top


def _module_name(path: Path) -> str:
    parts = path.relative_to(ROOT.parent).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def _imports(path: Path) -> set[str]:
    """Absolute names of the vehsim modules `path` imports."""
    name = _module_name(path)
    package = name if path.name == "__init__.py" else name.rpartition(".")[0]
    out = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Import):
            out |= {a.name for a in node.names if a.name.split(".")[0] == "vehsim"}
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = package.split(".")
                base = base[: len(base) - node.level + 1]
                mod = ".".join(base + ([node.module] if node.module else []))
            else:
                mod = node.module or ""
            if mod.split(".")[0] == "vehsim":
                out.add(mod)
                out |= {f"{mod}.{a.name}" for a in node.names}  # `from . import params`
    return out


def _unit(module: str) -> str | None:
    """The top-level unit of a vehsim module: `vehsim.tire.lugre` -> "tire"."""
    parts = module.split(".")
    if len(parts) == 1:
        return None
    return "cli" if parts[1] == "__main__" else parts[1]  # `python -m vehsim` is the CLI


GRAPH = {_module_name(p): _imports(p) for p in ROOT.rglob("*.py")}


def _existing(module: str) -> str:
    """The module itself, or its parent when `module` names an object inside it."""
    return module if module in GRAPH else module.rpartition(".")[0]


def test_model_packages_never_import_the_upper_layers():
    bad = []
    for mod, deps in GRAPH.items():
        unit = _unit(mod)
        if unit is None or unit in UPPER:
            continue
        bad += [f"{mod} -> {d}" for d in deps if _unit(_existing(d)) in UPPER]
    assert not bad, "model code imports a drawing, report or CLI module:\n" + "\n".join(bad)


@pytest.mark.parametrize("layer", UPPER)
def test_upper_layers_only_import_downwards(layer):
    rank = UPPER.index(layer)
    bad = [f"{mod} -> {d}" for mod, deps in GRAPH.items() if _unit(mod) == layer
           for d in deps if _unit(_existing(d)) in UPPER[rank + 1:]]
    assert not bad, "\n".join(bad)


def test_no_import_cycle_between_packages():
    edges: dict[str, set[str]] = {}
    for mod, deps in GRAPH.items():
        unit = _unit(mod)
        if unit is None:
            continue
        for d in deps:
            target = _unit(_existing(d))
            if target is not None and target != unit:
                edges.setdefault(unit, set()).add(target)
    # depth-first search for a back edge, reporting the cycle found
    state: dict[str, int] = {}
    path: list[str] = []

    def visit(u):
        state[u] = 1
        path.append(u)
        for v in sorted(edges.get(u, ())):
            if state.get(v) == 1:
                raise AssertionError("import cycle: " + " -> ".join(path[path.index(v):] + [v]))
            if v not in state:
                visit(v)
        path.pop()
        state[u] = 2

    for u in sorted(edges):
        if u not in state:
            visit(u)


def test_the_public_api_does_not_pull_in_the_upper_layers():
    deps = {_unit(_existing(d)) for d in GRAPH["vehsim"]}
    assert not deps & set(UPPER)


CORE = ("tire", "vehicle", "optimal", "control", "identify", "robot", "solvers", "drive")
"""The numerical core: functions of arrays and modules."""


def _external_imports(path: Path) -> set[str]:
    """Top-level names of the packages outside vehsim that `path` imports."""
    out = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Import):
            out |= {a.name.split(".")[0] for a in node.names}
        elif isinstance(node, ast.ImportFrom) and not node.level and node.module:
            out.add(node.module.split(".")[0])
    return out - {"vehsim"}


def test_the_core_never_touches_the_compilation_layer_threads_or_drawing():
    """No core module imports the compilation layer (`vehsim._compilation`: persistent
    cache, exported programs, work overlapped with compilation), threads, the command
    line's argparse or matplotlib."""
    bad = []
    for path in ROOT.rglob("*.py"):
        mod = _module_name(path)
        if _unit(mod) not in CORE:
            continue
        bad += [f"{mod} -> {d}" for d in GRAPH[mod] if _existing(d) == "vehsim._compilation"]
        bad += [f"{mod} -> {d}" for d in _external_imports(path)
                if d in ("threading", "concurrent", "argparse", "matplotlib")]
    assert not bad, "\n".join(bad)


IMPORT_PROBE = """
import importlib.metadata, json, sys
import vehsim
after_import = sorted(sys.modules)
from jax._src import xla_bridge
backend_started = bool(xla_bridge._backends)
import jax
jax.config.update("jax_num_cpu_devices", 2)  # refused once JAX's backend has started
from vehsim.cli import build_parser
build_parser()
after_parser = sorted(sys.modules)
try:
    import vehsim.sweep
    submodule = "imported"
except ImportError:
    submodule = "ImportError"
from vehsim import sweep, simulate
from vehsim.cli.brake import CONTROLLER_NAMES
from vehsim.control.experiments.scenarios import CONTROLLERS
try:
    vehsim.no_such_name
    missing = None
except AttributeError as e:
    missing = str(e)
names = json.loads(sys.argv[1])
print(json.dumps(dict(
    after_import=after_import, after_parser=after_parser, backend_started=backend_started,
    devices=len(jax.devices()), submodule=submodule,
    sweep=[sweep.__module__, type(sweep).__name__, sweep is vehsim.sweep],
    simulate=[simulate.__module__, type(simulate).__name__],
    half_car=vehsim.HalfCar.__module__, params=type(vehsim.params).__name__,
    unresolved=[n for n in names if getattr(vehsim, n, None) is None],
    version=[vehsim.__version__, importlib.metadata.version("vehsim")],
    controllers=[list(CONTROLLER_NAMES), list(CONTROLLERS)], missing=missing)))
"""


def _public_names() -> list[str]:
    """The names `vehsim/__init__.py` re-exports (``from ._x import f as f``)."""
    tree = ast.parse((ROOT / "__init__.py").read_text())
    return [a.asname or a.name for node in ast.walk(tree) if isinstance(node, ast.ImportFrom)
            for a in node.names if not (a.asname or a.name).startswith("_")]


def test_import_vehsim_binds_every_public_name_and_starts_no_backend():
    """`import vehsim` binds every public name eagerly (a plain package: its private
    implementation modules re-exported), starts no JAX backend (so the user can still
    configure JAX: devices, float64) and imports neither matplotlib, scipy nor xarray; the
    command line's parser adds none of them. `vehsim.sweep` and `vehsim.simulate` are the
    functions (their modules are private: ``import vehsim.sweep`` fails), an unknown name
    raises AttributeError, ``__version__`` is the installed metadata's, and the brake
    command's controller names are the controllers' keys."""
    import json
    import subprocess
    import sys

    names = _public_names()
    out = subprocess.run([sys.executable, "-c", IMPORT_PROBE, json.dumps(names)],
                         capture_output=True, text=True, cwd=ROOT.parent, check=True).stdout
    probe = json.loads(out)
    assert not probe["backend_started"] and probe["devices"] == 2
    for stage in ("after_import", "after_parser"):
        assert not [m for m in probe[stage] if m.split(".")[0] in ("matplotlib", "scipy",
                                                                   "xarray")], stage
    assert "vehsim.optimal.ip.solver" in probe["after_import"]  # eager
    assert probe["submodule"] == "ImportError"
    assert probe["sweep"] == ["vehsim._sweep", "function", True]
    assert probe["simulate"] == ["vehsim._simulate", "function"]
    assert probe["half_car"] == "vehsim.vehicle.half_car" and probe["params"] == "module"
    assert len(names) > 150 and probe["unresolved"] == []
    assert probe["version"][0] == probe["version"][1]
    assert "no_such_name" in probe["missing"]
    assert probe["controllers"][0] == probe["controllers"][1]


def test_vehsim_imports_from_a_zip_archive(tmp_path):
    """A plain package imports from anywhere Python's importers look, a zip archive among
    them (the package reads no source file of its own when imported)."""
    import subprocess
    import sys
    import zipfile

    archive = tmp_path / "vehsim.zip"
    with zipfile.ZipFile(archive, "w") as z:
        for path in ROOT.rglob("*"):
            if path.is_file() and "__pycache__" not in path.parts:
                z.write(path, path.relative_to(ROOT.parent).as_posix())
    probe = ("import vehsim; print(vehsim.__file__); "
             "print(vehsim.simulate.__module__, vehsim.rally_gravel().m > 0)")
    out = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True,
                         cwd=tmp_path, env={"PYTHONPATH": str(archive), "PATH": ""},
                         timeout=300)
    assert out.returncode == 0, out.stderr
    where, what = out.stdout.splitlines()
    assert where.startswith(str(archive)) and what == "vehsim._simulate True"
