"""The docs site builds with every warning an error, its parameter tables are the schema's, and the README
stays short with every link pointing at something that exists."""

from __future__ import annotations

import dataclasses
import re
import shutil
import subprocess
import sys
from dataclasses import dataclass
from pathlib import Path

import pytest

from deepbbs_ros.config import Config
from deepbbs_ros.config_doc import MARKER, field_comments, parameter_table, render
from deepbbs_ros.errors import ConfigError

REPO = Path(__file__).resolve().parents[1]
PAGES = sorted((REPO / "docs").rglob("*.md"))


def _build(root: Path, site: Path) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "mkdocs", "build", "--strict", "--config-file",
                           str(root / "mkdocs.yml"), "--site-dir", str(site)],
                          cwd=root, capture_output=True, text=True, timeout=300)


def test_site_builds_strict(tmp_path):
    res = _build(REPO, tmp_path / "site")
    out = res.stdout + res.stderr
    assert res.returncode == 0, out
    assert "WARNING" not in out, out
    for page in ("index.html", "node/index.html", "model/index.html", "architecture/index.html"):
        assert (tmp_path / "site" / page).is_file(), page


@pytest.mark.parametrize("broken", ["", "[gone](missing.md)", "[gone](node.md#no-such-section)",
                                    "`scripts/no_such_script.py`", "![gone](images/missing.png)"])
def test_site_build_fails_on_a_broken_link_or_a_missing_file(tmp_path, broken):
    """The validation is on: a link to a missing page or anchor, or a page naming a missing file, fails (and the
    same copy without it builds)."""
    root = tmp_path / "repo"
    shutil.copytree(REPO / "docs", root / "docs", ignore=shutil.ignore_patterns("__pycache__"))
    for name in ("mkdocs.yml", "README.md", "MODEL.md", "ARCHITECTURE.md"):
        shutil.copy(REPO / name, root / name)
    for folder in ("bags", "config", "deepbbs_ros", "launch", "msg_adapters", "rviz", "scripts", "tests"):
        if (REPO / folder).exists():
            (root / folder).symlink_to(REPO / folder)
    page = root / "docs" / "tools.md"
    page.write_text(page.read_text() + f"\nSee {broken}.\n")
    res = _build(root, tmp_path / "site")
    assert (res.returncode == 0) == (not broken), res.stdout + res.stderr


def test_parameter_tables_are_the_schema():
    """Every table between params markers is what the generator makes now (`python -m deepbbs_ros.config_doc`)."""
    stale = [p.relative_to(REPO) for p in PAGES if render(p.read_text()) != p.read_text()]
    assert not stale, f"out of date, run `python -m deepbbs_ros.config_doc`: {stale}"
    covered = {s for p in PAGES for m in MARKER.finditer(p.read_text()) for s in m.group(2).split(",")}
    assert covered == {f.name for f in dataclasses.fields(Config)}
    node_page = (REPO / "docs" / "node.md").read_text()
    node_sections = {s for m in MARKER.finditer(node_page) for s in m.group(2).split(",")}
    assert node_sections == {"node", "preprocess", "registration", "odometry"}  # what the node declares
    table = parameter_table(["node"])
    assert '| `node.mode` | str | `"pair"` |' in table
    assert "| `node.initial_pose` | list[float] | `[0.0, 0.0, 0.0, 0.0, 0.0, 0.0]` |" in table
    rows = [ln for ln in parameter_table([f.name for f in dataclasses.fields(Config)]).splitlines()[2:]]
    assert len(rows) == len(Config().to_flat())


@dataclass
class _Documented:
    # a comment about the group, kept off by the blank line

    a: float = 1.0  # m; on its line
    # above b
    b: int = 2
    c: bool = True  # on its line;
    # continued below

    d: str = "x"


@dataclass
class _Undocumented:
    a: float = 1.0  # m; fine
    b: int = 2


def test_field_comments():
    assert field_comments(_Documented) == {"a": "m; on its line", "b": "above b",
                                           "c": "on its line; continued below", "d": ""}
    assert field_comments(_Undocumented)["b"] == ""


def test_a_parameter_without_a_comment_fails(monkeypatch):
    import deepbbs_ros.config_doc as config_doc

    monkeypatch.setattr(config_doc, "_section_classes", lambda: {"node": _Undocumented})
    monkeypatch.setattr(config_doc, "Config", lambda: type("C", (), {"node": _Undocumented()})())
    with pytest.raises(ConfigError, match=r"node\.b has no comment"):
        config_doc.parameter_table(["node"])


def test_config_doc_check_cli(tmp_path):
    page = tmp_path / "page.md"
    page.write_text("# P\n\n<!-- params:odometry -->\nold\n<!-- /params -->\n")
    run = [sys.executable, "-m", "deepbbs_ros.config_doc"]
    assert subprocess.run([*run, "--check", str(page)], cwd=REPO, capture_output=True).returncode == 1
    assert subprocess.run([*run, str(page)], cwd=REPO, capture_output=True).returncode == 0
    assert "`odometry.gap_trust`" in page.read_text()
    assert subprocess.run([*run, "--check", str(page)], cwd=REPO, capture_output=True).returncode == 0


def test_readme_is_short_and_its_links_exist():
    text = (REPO / "README.md").read_text()
    assert len(text.encode()) <= 12 * 1024, f"README.md is {len(text.encode())} bytes (at most 12 KB)"
    targets = re.findall(r"\]\(([^)\s#]+)(?:#[^)\s]*)?\)", text)
    assert targets
    missing = [t for t in targets if not re.match(r"[a-z]+:", t) and not (REPO / t).exists()]
    assert not missing, missing
    # the site shows the README as its home page, where mkdocs checks its links and their anchors too
    assert (REPO / "docs" / "index.md").read_text().strip() == "<!-- include: README.md -->"


def test_a_page_link_out_of_docs_is_rewritten(tmp_path):
    """A page's link to a top-level file (../MODEL.md) points at the page that shows it; one to a missing file
    fails the build."""
    from importlib.util import module_from_spec, spec_from_file_location

    spec = spec_from_file_location("docs_hooks", REPO / "docs" / "hooks.py")
    hooks = module_from_spec(spec)
    spec.loader.exec_module(hooks)
    text = "See [the model card](../MODEL.md#limitations), [the defaults](../config/deepbbs_ros.yaml), [x](node.md)."
    assert hooks._rewrite(text, "docs/page.md", "page.md") == (
        "See [the model card](model.md#limitations), the defaults (`config/deepbbs_ros.yaml`), [x](node.md).")
    assert hooks._rewrite("[m](../../MODEL.md)", "docs/sub/page.md", "sub/page.md") == "[m](../model.md)"
