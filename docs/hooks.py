"""mkdocs hook: the site's pages are this folder's Markdown files (api/ included) and the
notebooks of ../notebooks, whatever docs_dir holds (mkdocs.yml explains why)."""

from pathlib import Path

from mkdocs.plugins import event_priority
from mkdocs.structure.files import File, Files


DOCS = Path(__file__).resolve().parent
SKIP = {"site"}


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
