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
