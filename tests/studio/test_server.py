"""Shared server pieces: two threads replacing the same scene node (the player's tick and
a GUI callback) are serialised, so neither dies on a handle removed under it."""

import threading

import numpy as np
import pytest

from fxspace.studio._server import Player, attach_stop, new_server, serialized


def test_serialized_draws_from_two_threads_never_collide():
    pytest.importorskip("viser", reason="viser not installed (pip install -e '.[viewer]')")
    server = new_server(0, environment_map=False)
    v = np.random.default_rng(0).normal(size=(30, 3)).astype(np.float32)
    f = np.array([[0, 1, 2], [2, 3, 4]], np.int32)
    calls, errors = [], []

    @serialized(server)
    def draw() -> None:
        server.scene.add_mesh_simple("/m", v, f, color=(200, 170, 140))
        calls.append(1)

    def hammer() -> None:
        try:
            for _ in range(150):
                draw()
        except Exception as e:  # what killed the navigator's player thread in CI
            errors.append(e)

    player = Player(draw, lambda: True, fps=1000.0)  # the tick, as the apps run it
    attach_stop(server, player)
    try:
        threads = [threading.Thread(target=hammer) for _ in range(2)]
        for t in threads:
            t.start()
        for t in threads:
            t.join(timeout=60)
    finally:
        server.stop()
    assert not errors, errors
    assert len(calls) >= 300
    assert not player._thread.is_alive()  # stopped with the server, not crashed earlier


def test_studio_lights_without_the_environment_map_unless_asked(monkeypatch, tmp_path):
    """``fxspace studio`` serves with a key + ambient light by default (viser's HDR
    environment map costs ~10 s to a software-rendered first frame); ``--environment-map``
    turns it on, and the flag reaches the app."""
    import fxspace.cli as cli
    import fxspace.studio as studio
    from fxspace.studio._server import ServeOptions

    assert ServeOptions().environment_map is False
    seen = []
    monkeypatch.setattr(cli, "studio_target", lambda target, out=None: tmp_path)
    monkeypatch.setattr(studio, "serve", lambda target, **kw: seen.append(kw))
    assert cli.main(["studio", str(tmp_path), "--port", "0"]) == 0
    assert cli.main(["studio", str(tmp_path), "--port", "0", "--environment-map"]) == 0
    assert [kw["environment_map"] for kw in seen] == [False, True]


def test_browser_config_opens_a_progress_page_then_the_app(tmp_path, chromium):
    """Issue 31.9: ``fxspace studio CONFIG`` answers at once with the progress of the
    app's stages (the waiting page), then the app opens on the same port and the page
    reconnects to it by itself; the run folder holds only the app's stages."""
    import socket
    import sys
    import threading
    from pathlib import Path

    from fxspace.config import dumps_toml
    from fxspace.runs import read_status
    from fxspace.studio import serve_config

    sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "pipelines"))
    from test_prepare_app import SMALL

    cfg = tmp_path / "rec.toml"
    cfg.write_text(dumps_toml(SMALL))
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    got = {}

    def open_app():
        got["app"] = serve_config(cfg, port=port, out=tmp_path / "run", block=False)

    th = threading.Thread(target=open_app, daemon=True)
    th.start()
    from playwright.sync_api import sync_playwright

    with sync_playwright() as p:
        b = p.chromium.launch(executable_path=chromium.exe, args=chromium.args)
        try:
            page = b.new_page()
            for _ in range(100):  # the waiting page answers within seconds
                try:
                    page.goto(f"http://127.0.0.1:{port}")
                    break
                except Exception:  # noqa: BLE001 - not listening yet
                    page.wait_for_timeout(200)
            page.get_by_text("preparing rec.toml", exact=False).wait_for(timeout=60_000)
            page.get_by_text("Edit keys:", exact=False).wait_for(timeout=240_000)  # the editor
        finally:
            b.close()
    th.join(timeout=60)
    server, ctl = got["app"]
    server.stop()
    assert server.get_port() == port and read_status(tmp_path / "run")["status"] == "partial"


def test_silent_drops_this_threads_lines_only(caplog):
    """`fxspace._progress.silent`: stage lines, notes and progress of the thread inside
    it are dropped (an app's warm-up repeats work the main thread says), another
    thread's are not."""
    from fxspace._progress import listening, note, progress, silent, stage

    caplog.set_level("INFO", logger="fxspace")
    heard = []
    with listening(heard.append):
        with silent():
            stage("hidden stage")
            note("hidden note")
            assert list(progress(range(3), "hidden bar")) == [0, 1, 2]
            other = threading.Thread(target=stage, args=("other thread",))
            other.start()
            other.join()
        stage("shown after")
        note("shown note")
    assert heard == ["other thread", "shown after", "shown note"]
    assert "shown note" in caplog.text
    assert "hidden" not in caplog.text  # the note's logger record too


def test_the_apps_warm_up_runs_beside_and_its_face_is_the_apps(monkeypatch):
    """``fxspace studio CONFIG`` starts the app module's ``warm(config, **kwargs)`` in a
    silent thread while the stages are prepared; a failure there is left to the app;
    the navigator's warm-up face is the one the app then takes (`studio_face` keeps it)."""
    import sys
    import types

    from fxspace.studio import _warm_up
    from fxspace.studio._faces import studio_face

    mod = types.ModuleType("fxspace_test_app")
    seen = []

    def warm(config, **kw):
        from fxspace._progress import stage

        stage("warming")  # silent
        seen.append((config, kw, threading.current_thread().name))

    def serve(target, port=0, **kw):
        return target

    mod.warm, mod.serve = warm, serve
    serve.__module__ = mod.__name__
    monkeypatch.setitem(sys.modules, mod.__name__, mod)
    t = _warm_up(serve, "cfg.toml", {"head": None})
    t.join(timeout=30)
    assert seen == [("cfg.toml", {"head": None}, "fxspace-warm")]
    mod.warm = lambda config, **kw: 1 / 0  # the app says what fails, not the warm-up
    _warm_up(serve, "cfg.toml", {}).join(timeout=30)
    del mod.warm
    assert _warm_up(serve, "cfg.toml", {}) is None  # no warm-up: nothing started

    rest = np.random.default_rng(0).normal(size=(12, 3)) * 30
    a = studio_face(rest, None, None, 500)
    assert studio_face(rest.copy(), None, None, 500) is a  # the same markers: kept
    assert studio_face(rest + 1.0, None, None, 500) is not a
