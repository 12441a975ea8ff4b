"""Issue 46.7: the architecture page is generated from the code and cannot drift."""

from __future__ import annotations

import importlib
import re
import shutil

import pytest

from fxspace.pipelines._architecture import (
    PAGE,
    ROOT,
    ArchitecturePageError,
    generated_blocks,
    layers,
    stale_blocks,
    write_architecture,
)


def test_the_page_matches_the_code():
    stale = stale_blocks()
    assert not stale, f"{PAGE} is out of date in {stale}: run `fxspace docs`"


def test_the_layers_are_the_contracts():
    rows = layers()
    assert rows[0] == ["fxspace.cli"] and rows[-1] == ["fxspace.errors"]
    body = generated_blocks()["layers"]
    for row in rows:
        for m in row:
            assert f"`{m}`" in body


def test_the_layout_lists_every_subpackage_and_module():
    body = generated_blocks()["layout"]
    pkg = ROOT / "fxspace"
    for p in pkg.iterdir():
        if p.is_dir() and (p / "__init__.py").is_file():
            assert f"  {p.name}/ " in body
        elif p.suffix == ".py" and p.name != "__init__.py":
            assert f"  {p.name} " in body


def test_every_fxspace_name_on_the_page_exists():
    """A dotted ``fxspace.…`` name in the prose must resolve (the page once named a
    ``fxspace.sitegen`` that did not exist)."""
    text = PAGE.read_text(encoding="utf-8")
    names = set(re.findall(r"\bfxspace(?:\.[A-Za-z_][A-Za-z0-9_]*)+", text))
    assert names
    missing = []
    for name in sorted(names):
        parts = name.split(".")
        for i in range(len(parts), 0, -1):
            try:
                obj = importlib.import_module(".".join(parts[:i]))
            except ImportError:
                continue
            try:
                for a in parts[i:]:
                    obj = getattr(obj, a)
            except AttributeError:
                missing.append(name)
            break
        else:
            missing.append(name)
    assert not missing, f"names on {PAGE.name} that do not exist: {missing}"


def test_a_changed_contract_makes_the_page_stale(tmp_path):
    """The check can fail: the page against a copy of the code with one more layer."""
    root = tmp_path / "src"
    (root / "tests").mkdir(parents=True)
    shutil.copy(ROOT / "tests" / "test_layout.py", root / "tests")
    text = (ROOT / "pyproject.toml").read_text(encoding="utf-8")
    (root / "pyproject.toml").write_text(
        text.replace('  "fxspace.errors",\n]', '  "fxspace.errors",\n  "fxspace.results",\n]', 1)
    )
    assert (root / "pyproject.toml").read_text() != text
    assert "layers" in stale_blocks(PAGE, root=root)
    page = tmp_path / "architecture.md"
    shutil.copy(PAGE, page)
    write_architecture(page, root=root)
    assert not stale_blocks(page, root=root)
    assert stale_blocks(page) == ["layers"]


def test_a_page_without_markers_is_refused(tmp_path):
    page = tmp_path / "architecture.md"
    page.write_text("# Architecture\n\nno markers\n")
    with pytest.raises(ArchitecturePageError, match="begin generated"):
        write_architecture(page)
    assert page.read_text() == "# Architecture\n\nno markers\n"
