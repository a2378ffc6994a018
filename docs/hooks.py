"""mkdocs hook: the site's pages are this folder's Markdown files (api/ included) and the
notebooks of ../notebooks, whatever docs_dir holds (mkdocs.yml explains why); and the maths of
every page is written as MathML when the site is built, so it renders with no JavaScript and no
network (a site copied to a shared drive or an air-gapped machine shows its equations).

The TeX comes from pymdownx.arithmatex in generic mode, in the pages and in the docstrings
(``<span class="arithmatex">\\(...\\)</span>``, ``<div class="arithmatex">\\[...\\]</div>``), and
from the Markdown cells of the notebooks (``$...$``, ``$$...$$``, left as text by nbconvert).
latex2mathml converts it; browsers render MathML Core natively (Chrome and Edge 109+, Firefox,
Safari). A formula it cannot convert stays as its TeX and the build warns, naming the page and
the formula, so a strict build fails."""

import html
import re
import xml.etree.ElementTree as ET
from pathlib import Path

from latex2mathml.converter import convert
from mkdocs.plugins import event_priority, get_plugin_logger
from mkdocs.structure.files import File, Files


DOCS = Path(__file__).resolve().parent
SKIP = {"site"}
MATHML = "http://www.w3.org/1998/Math/MathML"
log = get_plugin_logger("mathml")
counts = {"converted": 0, "failed": 0}


@event_priority(100)  # before mkdocs-jupyter wraps the notebooks
def on_files(files: Files, config) -> Files:
    def page(path: Path, root: Path) -> File:
        return File(path.relative_to(root).as_posix(), str(root), config["site_dir"],
                    config["use_directory_urls"])

    pages = [page(p, DOCS) for p in sorted(DOCS.rglob("*"))
             if p.is_file() and p.suffix in (".md", ".js", ".css", ".png")
             and not SKIP & set(p.relative_to(DOCS).parts)]
    notebooks = [page(p, DOCS.parent) for p in sorted((DOCS.parent / "notebooks").glob("*.ipynb"))]
    return Files(pages + notebooks)


# --- TeX -> MathML -------------------------------------------------------------------------------

OPERATORNAME = re.compile(r"\\operatorname\s*\{([^{}]*)\}")
CONTROL_SPACE = re.compile(r"(?<!\\)((?:\\\\)*)\\\s+")  # a backslash then a space or newline
# over-accents latex2mathml writes as a plain <mover>: dot, ddot, bar, tilde, check, vec, breve,
# acute, grave; MathML Core places them as accents (close to the base) only with accent="true"
ACCENTS = set("\u02d9\u00a8\u00af\u007e\u02dc\u02c7\u2192\u02d8\u00b4\u0060\u005e")


def tex_to_mathml(tex: str, display: bool) -> str:
    """The MathML of one TeX formula (without its delimiters); `ValueError` naming the reason when
    latex2mathml cannot convert it faithfully."""
    # latex2mathml loses \operatorname{atan2}; an upright name is what the TeX means
    tex = OPERATORNAME.sub(r"\\mathrm{\1}", tex)
    # TeX's control space written as a backslash at the end of a line: latex2mathml knows `\ `
    tex = CONTROL_SPACE.sub(r"\1\\ ", tex)
    try:
        text = convert(tex, display="block" if display else "inline")
    except Exception as e:  # latex2mathml's own errors have no common base
        raise ValueError(f"{type(e).__name__} {e}".strip()) from None
    try:  # it unescapes its own output: a `<` in \text{}, an `&` outside an environment
        math = ET.fromstring(text)
    except ET.ParseError as e:
        raise ValueError(f"malformed MathML ({e})") from None
    for el in math.iter():
        el.tag = el.tag.removeprefix(f"{{{MATHML}}}")
    for el in math.iter():
        # an unknown command is passed through as its name, e.g. <mi>\foo</mi>
        if el.text and el.text.startswith("\\") and len(el.text) > 1:  # not \backslash
            raise ValueError(f"unknown command {el.text}")
        if el.tag == "mo" and not (el.text or el.attrib or len(el)):  # \left. has attributes
            raise ValueError("an empty operator (a name lost on the way)")
        if "linebreak" in el.attrib:  # not in MathML Core
            raise ValueError("a line break (\\\\) outside an environment")
        if el.tag == "mover" and "accent" not in el.attrib and len(el) == 2:
            over = el[1]
            if over.tag == "mo" and over.text in ACCENTS:
                el.set("accent", "true")
    math.attrib.update(xmlns=MATHML, display="block" if display else "inline")
    return ET.tostring(math, encoding="unicode")


ARITHMATEX = re.compile(r'<(span|div) class="arithmatex">(.*?)</\1>', re.S)
DELIMITERS = {"span": (r"\(", r"\)"), "div": (r"\[", r"\]")}
# the Markdown cell of a notebook page (nbconvert's lab template); its end is found by nesting
MARKDOWN_CELL = re.compile(r'<div class="[^"]*\bjp-RenderedMarkdown\b[^"]*"[^>]*>')
VERBATIM = re.compile(r"(<(pre|code|script|style)\b.*?</\2>)", re.S)
# $$...$$ first; $...$ as pandoc reads it: no space inside either dollar, no digit after the last
DOLLARS = re.compile(r"\$\$(.+?)\$\$|(?<![\\$])\$(?=\S)([^$]+?)(?<=\S)(?<!\\)\$(?!\d)", re.S)


def _mathml(tex_html: str, display: bool, page: str, failures: list[str]) -> str | None:
    tex = html.unescape(tex_html).strip()
    try:
        mathml = tex_to_mathml(tex, display)
    except ValueError as e:
        failures.append(f"{page}: {tex!r} ({e})")
        return None
    return mathml


def _arithmatex(output: str, page: str, failures: list[str]) -> str:
    def replace(m: re.Match) -> str:
        tag, body = m.group(1), m.group(2)
        start, end = DELIMITERS[tag]
        tex = body.strip()
        if tex.startswith(start) and tex.endswith(end):  # an environment has no delimiters
            tex = tex[len(start):-len(end)]
        mathml = _mathml(tex, tag == "div", page, failures)
        return m.group(0) if mathml is None else f'<{tag} class="arithmatex">{mathml}</{tag}>'

    return ARITHMATEX.sub(replace, output)


def _dollars(fragment: str, page: str, failures: list[str]) -> str:
    def replace(m: re.Match) -> str:
        display = m.group(1) is not None
        mathml = _mathml(m.group(1) if display else m.group(2), display, page, failures)
        return m.group(0) if mathml is None else mathml

    parts = VERBATIM.split(fragment)  # [text, verbatim, tag name, text, ...]
    return "".join(DOLLARS.sub(replace, p) if i % 3 == 0 else p for i, p in enumerate(parts))


def _notebook_cells(output: str, page: str, failures: list[str]) -> str:
    pieces, pos = [], 0
    for m in MARKDOWN_CELL.finditer(output):
        if m.start() < pos:
            continue
        depth, end = 1, m.end()
        for tag in re.finditer(r"<(/?)div\b", output[m.end():]):
            depth += -1 if tag.group(1) else 1
            if depth == 0:
                end = m.end() + tag.start()
                break
        pieces += [output[pos:m.end()], _dollars(output[m.end():end], page, failures)]
        pos = end
    return "".join(pieces) + output[pos:]


def on_pre_build(config) -> None:
    counts.update(converted=0, failed=0)


@event_priority(-100)  # on the finished page, so the search index keeps the TeX
def on_post_page(output: str, page, config) -> str:
    failures: list[str] = []
    before = output.count("<math ")
    output = _arithmatex(output, page.file.src_uri, failures)
    if page.file.src_uri.endswith(".ipynb"):
        output = _notebook_cells(output, page.file.src_uri, failures)
    counts["converted"] += output.count("<math ") - before
    counts["failed"] += len(failures)
    for failure in failures:
        log.warning(f"formula left as TeX, latex2mathml cannot convert it: {failure}")
    return output


def on_post_build(config) -> None:
    log.info(f"{counts['converted']} formulas written as MathML, {counts['failed']} left as TeX")
