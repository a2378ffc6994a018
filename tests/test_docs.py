"""The documentation site: every public name of vehsim has a docstring and a page in the API
reference, and `mkdocs build --strict` succeeds (a broken reference, link or anchor fails),
rendering every notebook with the outputs stored in it, without executing it."""

import ast
import importlib
import os
import re
import subprocess
import sys
from pathlib import Path

import pytest


ROOT = Path(__file__).parent.parent
API = ROOT / "docs" / "api"


def public_names() -> list[str]:
    """The names `vehsim/__init__.py` exports (its ``from ... import x as x`` lines)."""
    tree = ast.parse((ROOT / "vehsim" / "__init__.py").read_text())
    names = [a.asname or a.name for node in ast.walk(tree) if isinstance(node, ast.ImportFrom)
             for a in node.names]
    return [n for n in names if not n.startswith("_")]


def documented() -> dict[str, str]:
    """``{identifier: page}`` for every ``::: identifier`` directive of docs/api/."""
    return {m.group(1): page.name for page in sorted(API.glob("*.md"))
            for m in re.finditer(r"^::: ([\w.]+)\s*$", page.read_text(), re.M)}


def resolve(identifier: str):
    """The object a mkdocstrings identifier names (a module, or an attribute of one)."""
    parts = identifier.split(".")
    for i in range(len(parts), 0, -1):
        try:
            obj = importlib.import_module(".".join(parts[:i]))
        except ImportError:
            continue
        for name in parts[i:]:
            obj = getattr(obj, name)
        return obj
    raise ImportError(identifier)


def test_every_public_name_has_a_docstring_and_a_page():
    griffe = pytest.importorskip("griffe")
    import vehsim

    package = griffe.load("vehsim", search_paths=[str(ROOT)])
    pages = {id(resolve(ident)): ident for ident in documented()}
    missing, undocumented = [], []
    for name in public_names():
        ident = pages.get(id(getattr(vehsim, name)))
        if ident is None:
            missing.append(name)
            continue
        obj = package[ident.removeprefix("vehsim.")] if ident != "vehsim" else package
        if not (obj.docstring and obj.docstring.value.strip()):
            undocumented.append(f"{name} ({ident})")
    assert not missing, ("public names with no page; add `::: <module>.<name>` to a page of "
                         f"docs/api/: {missing}")
    assert not undocumented, f"public names without a docstring: {undocumented}"
    assert len(public_names()) > 100  # the parse found the export list


def test_docs_build_strict_renders_every_page_and_notebook(tmp_path):
    pytest.importorskip("mkdocs")
    pytest.importorskip("mkdocstrings")
    nbformat = pytest.importorskip("nbformat")
    site = tmp_path / "site"
    out = subprocess.run(
        [sys.executable, "-m", "mkdocs", "build", "--strict", "-f", str(ROOT / "docs" /
                                                                         "mkdocs.yml"),
         "-d", str(site)], capture_output=True, text=True, timeout=600,
        env=dict(os.environ, NO_MKDOCS_2_WARNING="1"))
    assert out.returncode == 0, out.stdout + out.stderr
    assert "Converting notebook (execute=False)" in out.stderr  # rendered, never executed
    pages = sorted(p.relative_to(site).parent.as_posix() for p in site.rglob("index.html"))
    assert {"api/tires", "report-map", "sweeps", "maneuvers", "performance"} <= set(pages)
    # each API object has its anchor, so a cross-reference to it resolves
    html = {p: (site / p / "index.html").read_text() for p in pages if p.startswith("api/")}
    for ident, page in documented().items():
        assert f'id="{ident}"' in html[f"api/{page.removesuffix('.md')}"], ident
    # every notebook has a page, with as many figures as its stored outputs have
    for nb_path in sorted((ROOT / "notebooks").glob("*.ipynb")):
        page = (site / "notebooks" / nb_path.stem / "index.html").read_text()
        nb = nbformat.read(nb_path, as_version=4)
        figures = sum("image/png" in o.get("data", {}) for c in nb.cells
                      if c.cell_type == "code" for o in c.outputs)
        assert page.count("<img") >= figures, nb_path.name
    print(f"{len(pages)} pages")
