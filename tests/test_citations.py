"""Issue 44.6: the four papers cited (authors, title, venue and year as the paper's header
prints them) in README.md, each paper's guide and its generated reproduction page, all
from one table (`fxspace.pipelines._citations.CITATIONS`), and nothing in a citation
that the paper's text does not print."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

from fxspace.pipelines._citations import CITATIONS
from fxspace.pipelines._docs import PAPERS

ROOT = Path(__file__).resolve().parents[1]
PAPER_DIR = ROOT.parent / "shared" / "papers"


def test_one_citation_per_paper_on_every_page():
    assert set(CITATIONS) == set(PAPERS)
    readme = (ROOT / "README.md").read_text()
    assert "## Papers" in readme
    for key, cit in CITATIONS.items():
        assert "as printed in the paper's header" in cit, key
        assert cit in readme, f"README.md lacks the citation of {key}"
        guide = (ROOT / "docs" / "guides" / f"paper-{key}.md").read_text()
        assert f"**Paper:** {cit}" in guide, f"paper-{key}.md lacks its citation"
        page = (ROOT / "docs" / "reproductions" / f"{key}.md").read_text()
        assert f"**Citation:** {cit}" in page, f"reproductions/{key}.md lacks its citation"


def _squash(s: str) -> str:
    return re.sub(r"[\s*\\\[\]^†]+", "", s)


@pytest.mark.parametrize("key", sorted(CITATIONS))
def test_the_citation_is_what_the_paper_prints(key):
    """Title and every author's name as the text prints them (spaces aside: the texts are
    extracted from PDFs); the venue only where the header names it."""
    src = PAPER_DIR / Path(PAPERS[key].source).name
    if not src.is_file():
        pytest.skip(f"the paper's text is absent ({src})")
    head = _squash(src.read_text()[:3000])
    cit = CITATIONS[key]
    titles = re.findall(r'"([^"]+)"', cit) + re.findall(r"\(([^()]*[가-힣ぁ-ん][^()]*)\)", cit)
    assert titles and all(_squash(t) in head for t in titles), (key, titles)
    authors = cit.split(", \"")[0]
    names = [n for n in re.split(r",| and |\([^)]*\)", authors) if n.strip()]
    assert len(names) >= 2 and all(_squash(n) in head for n in names), (key, names)
    if "Journal" in cit:
        assert "Journal of the Korea Computer Graphics Society" in src.read_text()[:300]
    else:
        assert "no venue is printed" in cit or "neither is printed" in cit
