"""The pages people read: README stays short, every docs page is in the site's nav, and
every image the README shows exists (the site's home page is the README, docs/hooks.py)."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
DOCS = ROOT / "docs"


def _nav_pages() -> set[str]:
    text = (ROOT / "mkdocs.yml").read_text(encoding="utf-8")
    nav = text.split("\nnav:\n", 1)[1].split("\n\n", 1)[0]
    return set(re.findall(r":\s*(\S+\.md)\s*$", nav, flags=re.M))


def test_readme_at_most_200_lines():
    n = len((ROOT / "README.md").read_text(encoding="utf-8").splitlines())
    assert n <= 200, f"README.md has {n} lines; move detail into docs/ pages"


def test_readme_keeps_the_set_up_and_test_commands():
    text = (ROOT / "README.md").read_text(encoding="utf-8")
    assert 'pip install -e ".[dev]" && fxspace demo' in text
    assert "python -m pytest" in text


def test_every_docs_page_is_in_the_nav():
    pages = {p.relative_to(DOCS).as_posix() for p in DOCS.rglob("*.md")}
    nav = _nav_pages()
    assert pages, "no docs pages found"
    missing = sorted(pages - nav)
    assert not missing, f"pages not in mkdocs.yml nav: {missing}"
    dangling = sorted(nav - pages)
    assert not dangling, f"nav entries without a page: {dangling}"


@pytest.mark.parametrize("name", ["README.md"])
def test_readme_links_and_images_resolve(name):
    text = (ROOT / name).read_text(encoding="utf-8")
    targets = re.findall(r"\]\(((?!https?://|#)[^)]+)\)", text)
    assert targets, "README links to nothing"
    for t in targets:
        assert (ROOT / t.split("#")[0]).exists(), f"{name} links to missing {t}"
