"""mkdocs hook: the home page is the repository README (one source of truth).

Paths that point into ``docs/`` from the repository root are rewritten to be relative to
the site, and links to repository files outside ``docs/`` become plain code spans.
"""

from __future__ import annotations

import re
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent


def on_page_read_source(page, config):
    if page.file.src_uri != "index.md":
        return None
    text = (ROOT / "README.md").read_text(encoding="utf-8")
    text = text.replace("](docs/", "](")
    # links to files of the repository that are not part of the site: keep the text only
    def keep_or_code(m: re.Match) -> str:
        target = m.group(2)
        if re.match(r"https?://|#", target) or (ROOT / "docs" / target.split("#")[0]).is_file():
            return m.group(0)
        return f"{m.group(1)} (`{target}`)"

    return re.sub(r"\[([^\]]+)\]\(([^)]+)\)", keep_or_code, text)


# Maths without a CDN and without JavaScript: pymdownx.arithmatex (generic mode) leaves
# \( … \) and \[ … \] in elements of class "arithmatex"; each becomes MathML at build time,
# which browsers render natively, offline.
_MATH = re.compile(
    r'<(span|div) class="arithmatex">\s*(?:\\\((.*?)\\\)|\\\[(.*?)\\\])\s*</\1>', re.S
)


def _to_mathml(m: re.Match) -> str:
    import html

    from latex2mathml.converter import convert

    inline = m.group(2) is not None
    tex = html.unescape(m.group(2) if inline else m.group(3)).strip()
    try:
        mathml = convert(tex, display="inline" if inline else "block")
    except Exception as exc:  # noqa: BLE001 — name the formula that failed, never drop it
        raise ValueError(f"docs: cannot convert TeX to MathML: {tex!r} ({exc})") from exc
    tag = "span" if inline else "div"
    return f'<{tag} class="arithmatex">{mathml}</{tag}>'


def on_page_content(html, page, config, files):
    return _MATH.sub(_to_mathml, html)
