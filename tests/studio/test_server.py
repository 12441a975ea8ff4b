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
