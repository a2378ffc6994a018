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


LAZY_PROBE = """
import json, sys
import vehsim
after_import = sorted(sys.modules)
from vehsim.cli import build_parser
build_parser()
after_parser = sorted(sys.modules)
import vehsim.simulate, vehsim.sweep
from vehsim.cli.brake import CONTROLLER_NAMES
from vehsim.control.experiments.scenarios import CONTROLLERS
try:
    vehsim.no_such_name
    missing = None
except AttributeError as e:
    missing = str(e)
print(json.dumps(dict(
    after_import=after_import, after_parser=after_parser,
    sweep=[vehsim.sweep.__module__, type(vehsim.sweep).__name__],
    simulate=[vehsim.simulate.__module__, type(vehsim.simulate).__name__],
    half_car=vehsim.HalfCar.__module__, params=type(vehsim.params).__name__,
    resolved=sum(getattr(vehsim, n) is not None for n in vehsim.__all__),
    all=len(vehsim.__all__), in_dir=set(vehsim.__all__) <= set(dir(vehsim)),
    controllers=[list(CONTROLLER_NAMES), list(CONTROLLERS)], missing=missing)))
"""


def test_public_names_are_bound_on_first_use():
    """`import vehsim` loads no model, and building the command line loads none of the
    controllers, robots or solvers (a command imports what it runs); each public name
    imports its module when first asked for, `vehsim.sweep` and `vehsim.simulate` stay the
    functions after their modules are imported, an unknown name raises AttributeError, and
    the brake command's controller names are the controllers' keys."""
    import json
    import subprocess
    import sys

    out = subprocess.run([sys.executable, "-c", LAZY_PROBE], capture_output=True, text=True,
                         cwd=ROOT.parent, check=True).stdout
    probe = json.loads(out)
    loaded = {m for m in probe["after_import"] if m.startswith("vehsim.")}
    assert loaded == {"vehsim._xla_cpu"}
    assert "diffrax" not in probe["after_import"] and "equinox" not in probe["after_import"]
    heavy = ("vehsim.control.controllers.braking", "vehsim.robot", "vehsim.optimal.ip.solver",
             "vehsim.tire.moments", "vehsim.identify.fit")
    assert not [m for m in probe["after_parser"] if m.startswith(heavy)]
    assert probe["sweep"] == ["vehsim.sweep", "function"]
    assert probe["simulate"] == ["vehsim.simulate", "function"]
    assert probe["half_car"] == "vehsim.vehicle.half_car" and probe["params"] == "module"
    assert probe["resolved"] == probe["all"] > 150 and probe["in_dir"]
    assert "no_such_name" in probe["missing"]
    assert probe["controllers"][0] == probe["controllers"][1]
