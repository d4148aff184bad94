"""mkdocs hook: pages that include a Markdown file from the top of the repository, and a check of every page.

A page whose text is ``<!-- include: MODEL.md -->`` becomes that file's text, with its links rewritten for
the site: a link or picture into ``docs/`` points at the page or file, a link to README.md / MODEL.md /
ARCHITECTURE.md at the page that shows it, a link to another file of the repository becomes its path in
code. A page's own links out of ``docs/`` (``../MODEL.md``) are rewritten the same way. Every page, included
files too, is checked for paths into the repository's folders (``scripts/...``, ``config/...``) that do not
exist. A link to a missing file, or such a path, is a warning, which ``mkdocs build --strict`` turns into an
error.
"""

from __future__ import annotations

import logging
import posixpath
import re
from pathlib import Path

log = logging.getLogger("mkdocs.plugins.deepbbs_ros")
ROOT = Path(__file__).resolve().parents[1]
INCLUDE = re.compile(r"^<!-- include: (\S+) -->\s*$", re.M)
LINK = re.compile(r"(!?)\[([^\]]*)\]\(([^)\s#]+)(#[^)\s]*)?\)")
# a path into one of the repository's folders, in text, code or a command: it must exist
FOLDERS = "bags|config|deepbbs_ros|docs|launch|msg_adapters|rviz|scripts|tests"
REPO_PATH = re.compile(rf"(?<![\w/.~$<{{-])((?:{FOLDERS})/[\w./-]*)")
PAGES = {"README.md": "index.md", "MODEL.md": "model.md", "ARCHITECTURE.md": "architecture.md"}


def _rewrite(text: str, name: str, page_src: str) -> str:
    """Links of ``text`` (the file ``name``, relative to the repository) for the page ``page_src``."""
    here = posixpath.dirname(name)
    where = name if name == f"docs/{page_src}" else f"{name} (included in {page_src})"

    def link(m: re.Match) -> str:
        bang, label, target, anchor = m.group(1), m.group(2), m.group(3), m.group(4) or ""
        if re.match(r"[a-z]+:", target):  # https:, mailto:
            return m.group(0)
        path = posixpath.normpath(posixpath.join(here, target))
        if path.startswith("docs/") and name.startswith("docs/"):
            return m.group(0)  # a page's own link into the site: mkdocs checks it
        if not (ROOT / path).exists():
            log.warning(f"{where} links to {target}, which is not in the repository")
            return m.group(0)
        if path in PAGES:
            path = "docs/" + PAGES[path]
        if path.startswith("docs/"):
            rel = posixpath.relpath(path[len("docs/"):], posixpath.dirname(page_src) or ".")
            return f"{bang}[{label}]({rel}{anchor})"
        if bang:
            log.warning(f"{where} shows {target}: keep pictures under docs/")
            return m.group(0)
        return label if label.strip("`") == path else f"{label} (`{path}`)"

    return LINK.sub(link, text)


def on_page_markdown(markdown: str, page, config, files) -> str:
    def include(m: re.Match) -> str:
        name = m.group(1)
        path = ROOT / name
        if not path.is_file():
            log.warning(f"{page.file.src_uri} includes {name}, which is not in the repository")
            return ""
        return _rewrite(path.read_text(), name, page.file.src_uri)

    markdown = INCLUDE.sub(include, markdown)
    # a page's own links out of docs/ (../MODEL.md, ../config/deepbbs_ros.yaml) are rewritten the same way
    markdown = _rewrite(markdown, f"docs/{page.file.src_uri}", page.file.src_uri)
    for path in sorted({m.group(1).rstrip(".") for m in REPO_PATH.finditer(markdown)}):
        if not (ROOT / path).exists():
            log.warning(f"{page.file.src_uri} names {path}, which is not in the repository")
    return markdown
