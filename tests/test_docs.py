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


def test_site_loads_nothing_from_the_network():
    text = (ROOT / "mkdocs.yml").read_text(encoding="utf-8")
    assert "http://" not in text and "https://" not in text, "mkdocs.yml loads a URL"


def test_maths_become_mathml_at_build_time():
    pytest.importorskip("latex2mathml", reason="docs extra not installed (pip install -e .[docs])")
    import importlib.util

    spec = importlib.util.spec_from_file_location("docs_hooks", DOCS / "hooks.py")
    hooks = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(hooks)
    html = (
        '<p>a <span class="arithmatex">\\( x_i &lt; 1 \\)</span></p>'
        '<div class="arithmatex">\\[ \\sum_k u_{ik} = 1 \\]</div>'
    )
    out = hooks.on_page_content(html, None, None, None)
    assert "\\(" not in out and "\\[" not in out
    assert out.count("<math") == 2
    assert 'display="block"' in out and "<mo>&#x0003C;</mo>" in out
