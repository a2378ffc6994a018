"""The documentation site: every public name of vehsim has a docstring and a page in the API
reference, and `mkdocs build --strict` succeeds (a broken reference, link or anchor fails),
rendering every notebook with the outputs stored in it, without executing it."""

import ast
import html
import importlib
import importlib.util
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


@pytest.fixture(scope="module")
def site(tmp_path_factory):
    """The site built once with `mkdocs build --strict`: (its folder, the build's stderr)."""
    pytest.importorskip("mkdocs")
    pytest.importorskip("mkdocstrings")
    pytest.importorskip("latex2mathml")
    site = tmp_path_factory.mktemp("docs") / "site"
    out = subprocess.run(
        [sys.executable, "-m", "mkdocs", "build", "--strict", "-f", str(ROOT / "docs" /
                                                                         "mkdocs.yml"),
         "-d", str(site)], capture_output=True, text=True, timeout=600,
        env=dict(os.environ, NO_MKDOCS_2_WARNING="1"))
    assert out.returncode == 0, out.stdout + out.stderr
    return site, out.stderr


def test_docs_build_strict_renders_every_page_and_notebook(site):
    nbformat = pytest.importorskip("nbformat")
    site, stderr = site
    assert "Converting notebook (execute=False)" in stderr  # rendered, never executed
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


def math_texts(page: str) -> set[str]:
    """The text of every MathML formula of a page, tags removed: `α=atan2(−vy,vx)`."""
    return {html.unescape(re.sub(r"<[^>]*>", "", m))
            for m in re.findall(r"<math\b[^>]*>(.*?)</math>", page, re.S)}


def test_docs_site_works_offline_with_the_maths_as_mathml(site):
    """The built site fetches nothing from the network (no script, stylesheet or image from a
    URL; fonts are off in mkdocs.yml), and its maths, from a page, a docstring and a notebook, is
    MathML that browsers render without JavaScript; no formula is left as TeX."""
    site, stderr = site
    remote = re.compile(r"^(https?:)?//", re.I)
    for path in site.rglob("*.html"):
        page = path.read_text()
        for tag, attr, url in re.findall(r"<(script|link|img)\b[^>]*?\b(src|href)=\"([^\"]*)\"",
                                         page):
            assert not remote.match(url), f"{path.relative_to(site)}: <{tag} {attr}={url!r}>"
        assert "mathjax" not in page.lower() or path.parent.parent.name == "notebooks", path
        # arithmatex's TeX is gone: every span/div of it holds a <math> element
        assert not re.search(r'class="arithmatex">\s*\\[(\[]', page), path
    report_map = (site / "report-map" / "index.html").read_text()  # a Markdown page
    assert "s=x3−x1x2/2" in math_texts(report_map)
    tires = (site / "api" / "tires" / "index.html").read_text()  # a docstring
    assert "α=atan2(−vy,vx)" in math_texts(tires)
    notebook = (site / "notebooks" / "combined_slip_tires" / "index.html").read_text()
    assert "κ=0" in math_texts(notebook) and "$\\kappa = 0$" not in notebook
    assert re.search(r"(\d+) formulas written as MathML, 0 left as TeX", stderr), stderr[-2000:]
    assert int(re.search(r"(\d+) formulas written as MathML", stderr).group(1)) > 500


def load_hooks():
    spec = importlib.util.spec_from_file_location("docs_hooks", ROOT / "docs" / "hooks.py")
    hooks = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(hooks)
    return hooks


def test_docs_mathml_conversion_and_a_formula_it_cannot_convert(caplog):
    """The TeX macros the docstrings use come out as MathML Core renders them (an accent sits on
    its letter, \\operatorname keeps its name, a backslash-newline is a space); a formula
    latex2mathml cannot convert stays on the page as TeX and the build warns with it."""
    pytest.importorskip("mkdocs")
    pytest.importorskip("latex2mathml")
    hooks = load_hooks()
    dot = hooks.tex_to_mathml(r"\tau\dot F_n = \bar z", display=False)
    assert dot.count('<mover accent="true">') == 2 and 'display="inline"' in dot
    atan2 = hooks.tex_to_mathml(r"\operatorname{atan2}(y, x)", display=True)
    assert math_texts(atan2) == {"atan2(y,x)"} and atan2.count('mathvariant="normal"') == 4
    assert "\\" not in hooks.tex_to_mathml("p,\\\n  b = 1", True)
    for bad in [r"\foo x", "x_", r"\text{a<b}", r"a \\ b"]:
        with pytest.raises(ValueError):
            hooks.tex_to_mathml(bad, display=False)

    class Page:
        class file:
            src_uri = "notebooks/x.ipynb"

    page = ('<p><span class="arithmatex">\\(\\foo + x\\)</span> and '
            '<span class="arithmatex">\\(y &lt; 1\\)</span></p>'
            '<div class="jp-RenderedHTMLCommon jp-RenderedMarkdown">'
            '<p>$\\kappa$ costs $5 and <code>$HOME$</code> $$\\frac{a}{b}$$</p></div><p>$z$</p>')
    with caplog.at_level("WARNING"):
        out = hooks.on_post_page(page, Page, {})
    assert '<span class="arithmatex">\\(\\foo + x\\)</span>' in out  # left as TeX, and said
    assert [r.levelname for r in caplog.records] == ["WARNING"]
    assert "\\foo + x" in caplog.records[0].getMessage()
    assert math_texts(out) == {"y<1", "κ", "ab"}  # not $5, not code, not outside a cell
    assert "<code>$HOME$</code>" in out and "<p>$z$</p>" in out


def _cli_options():
    """``(command, option strings, allowed words or None)`` for every argument of every
    ``vehsim`` subcommand (a nested one, such as ``tire show``, under its parent's name)."""
    import argparse

    from vehsim.cli import build_parser

    def walk(command, parser):
        for action in parser._actions:
            if isinstance(action, argparse._SubParsersAction):
                for sub in action.choices.values():
                    yield from walk(command, sub)
            elif "--help" not in action.option_strings:
                names = getattr(action.type, "names", None) or action.choices
                yield command, action.option_strings or [action.dest], names

    (commands,) = [a for a in build_parser()._actions
                   if isinstance(a, argparse._SubParsersAction)]
    for command, parser in commands.choices.items():
        yield from walk(command, parser)


def test_command_line_page_names_every_option_and_its_words():
    """docs/cli.md, under each subcommand's heading, names each of its long options; where
    an option's table row lists the words it accepts (rather than pointing to ``--help``),
    it lists every one of them, so that a new controller or mode cannot go undocumented."""
    text = (ROOT / "docs" / "cli.md").read_text()
    sections = {part.splitlines()[0].strip("`"): part
                for part in re.split(r"^## ", text, flags=re.M)[1:]}
    checked = 0
    for command, options, names in _cli_options():
        section = sections[f"vehsim {command}"]
        for option in (o for o in options if not o.startswith("-") or o.startswith("--")):
            assert option in section, (command, option)
        if not names or not options[0].startswith("--"):
            continue
        rows = [ln for ln in section.splitlines() if ln.startswith(f"| `{options[0]}")]
        assert rows, (command, options[0])
        if "--help" in rows[0]:
            continue
        missing = [n for n in names if f"`{n}`" not in rows[0]]
        assert not missing, (command, options[0], missing)
        checked += 1
    assert checked >= 5
