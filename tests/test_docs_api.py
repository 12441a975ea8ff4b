"""Issue 18, item 6: the API site is written per symbol, every `::: name` resolves, the
examples run, and the built HTML shows no raw Sphinx roles."""

from __future__ import annotations

import importlib
import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
API = ROOT / "docs" / "api"
ROLE = re.compile(r":(?:func|class|mod|data|attr|meth|obj|exc):(?:`|<code>)")
DIRECTIVE = re.compile(r"^::: (\S+)", re.M)
# every public name of these fronts has its own `::: name` entry on some page
DOCUMENTED = ("expression", "cluster", "navigation", "controlpoints", "mesh", "motion", "results")


def _directives() -> list[tuple[str, str]]:
    return [(p.name, m) for p in sorted(API.glob("*.md")) for m in DIRECTIVE.findall(p.read_text())]


def _resolve(dotted: str):
    parts = dotted.split(".")
    for cut in range(len(parts), 0, -1):
        try:
            obj = importlib.import_module(".".join(parts[:cut]))
        except ImportError:
            continue
        for attr in parts[cut:]:
            obj = getattr(obj, attr)
        return obj
    raise ImportError(dotted)


def test_every_directive_resolves_and_is_one_symbol():
    found = _directives()
    assert len(found) > 200
    bad = []
    for page, name in found:
        try:
            obj = _resolve(name)
        except (ImportError, AttributeError) as e:
            bad.append(f"{page}: {name} ({e})")
            continue
        if type(obj).__name__ == "module":
            bad.append(f"{page}: {name} is a whole module; list its symbols instead")
    assert not bad, "\n".join(bad)


def test_every_public_name_has_an_entry():
    shown = set()
    for _, name in _directives():
        try:
            shown.add(id(_resolve(name)))
        except (ImportError, AttributeError):
            pass
    missing = []
    for sub in DOCUMENTED:
        mod = importlib.import_module(f"fxspace.{sub}")
        for name in mod.__all__:
            obj = getattr(mod, name)
            if callable(obj) and id(obj) not in shown:
                missing.append(f"fxspace.{sub}.{name}")
    assert not missing, "public names without a `::: name` entry in docs/api:\n" + "\n".join(
        missing
    )


def test_system_pages_open_with_pipeline_and_example():
    for name in ("expression", "navigation", "controlpoints", "motion", "mesh"):
        text = (API / f"{name}.md").read_text()
        head = text.split("\n## ", 1)[0]
        assert re.search(r"^1\. .*^2\. .*^3\. ", head, re.S | re.M), name
        assert "```python" in head, name


@pytest.mark.slow
def test_built_site_has_no_raw_roles(tmp_path):
    if shutil.which("mkdocs") is None:
        pytest.skip("mkdocs is not installed (pip install -e '.[docs]')")
    site = tmp_path / "site"
    env = {**os.environ, "NO_MKDOCS_2_WARNING": "1"}
    r = subprocess.run(
        ["mkdocs", "build", "--strict", "--quiet", "-d", str(site)],
        cwd=ROOT,
        capture_output=True,
        text=True,
        env=env,
    )
    assert r.returncode == 0, r.stderr[-3000:]
    raw = []
    for page in site.rglob("*.html"):
        for m in ROLE.finditer(page.read_text(encoding="utf-8")):
            raw.append(f"{page.relative_to(site)}: {m.group(0)}")
    assert not raw, "raw Sphinx roles on the built site:\n" + "\n".join(raw[:40])


def _examples():
    for page in sorted(API.glob("*.md")):
        for i, block in enumerate(re.findall(r"```python\n(.*?)```", page.read_text(), re.S)):
            yield pytest.param(block, id=f"{page.stem}-{i}")


@pytest.mark.slow
@pytest.mark.parametrize("code", list(_examples()))
def test_page_examples_run(code, tmp_path, request):
    env = {**os.environ, "MPLBACKEND": "Agg"}
    if "data_path" in code:  # the real-data examples skip where the data is absent
        env["FXSPACE_DATA"] = str(request.getfixturevalue("data_dir"))
    r = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, cwd=tmp_path, env=env
    )
    assert r.returncode == 0, r.stderr[-3000:]
