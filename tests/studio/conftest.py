"""Shared set-up of the browser tests: viser, playwright and headless Chromium, each
skipped with the reason (and the fix) where it is absent."""

from __future__ import annotations

import contextlib
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
    """``.pw`` (``playwright.sync_api``), ``.exe`` (the Chromium binary), ``.args``,
    ``.page(server, viewport=None)`` (a context manager: a page on the app) and
    ``.field(page, label)`` (a labelled GUI input)."""
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

    @contextlib.contextmanager
    def page(server, viewport=None):
        """A headless page on ``server``'s app; the browser closed and the server stopped
        on the way out, whatever happens inside."""
        try:
            with pw.sync_playwright() as p:
                browser = p.chromium.launch(executable_path=exe, args=CHROMIUM_ARGS)
                try:
                    pg = browser.new_page(viewport=viewport) if viewport else browser.new_page()
                    pg.goto(f"http://127.0.0.1:{server.get_port()}")
                    yield pg
                finally:
                    browser.close()
        finally:
            server.stop()

    return SimpleNamespace(pw=pw, exe=exe, args=CHROMIUM_ARGS, page=page, field=gui_input)


def gui_input(page, label: str):
    """The text/number input of the viser GUI control labelled ``label``."""
    return page.locator(
        f"xpath=//label[text()='{label}']/ancestor::div"
        "[contains(@class,'mantine-Flex-root')][1]//input"
    )
