"""Shared set-up of the browser tests: viser, playwright and headless Chromium, each
skipped with the reason (and the fix) where it is absent."""

from __future__ import annotations

import os
import shutil
from types import SimpleNamespace

import pytest

#: Chromium flags for a headless run in a sandbox without a GPU or a network
CHROMIUM_ARGS = [
    "--no-sandbox",
    "--disable-gpu",
    "--disable-background-networking",
    "--disable-component-update",
    "--no-first-run",
    "--disable-sync",
]


@pytest.fixture
def chromium():
    """``.pw`` (``playwright.sync_api``), ``.exe`` (the Chromium binary) and ``.args``."""
    pytest.importorskip("viser", reason="viser not installed (pip install -e '.[viewer]')")
    pw = pytest.importorskip(
        "playwright.sync_api", reason="playwright not installed (pip install -e '.[viewer]')"
    )
    exe = (
        os.environ.get("FXSPACE_CHROMIUM")
        or shutil.which("chromium")
        or shutil.which("chromium-browser")
    )
    if exe is None:
        pytest.skip("Chromium not found (apt-get install chromium, or set FXSPACE_CHROMIUM)")
    return SimpleNamespace(pw=pw, exe=exe, args=CHROMIUM_ARGS)
