"""Shortest-path rows split between worker processes (`fxspace.expression._row_workers`):
the same scipy Dijkstra as in one process, bit for bit, and nothing silent when a worker
dies or the setting is wrong."""

from __future__ import annotations

import os
import subprocess
import sys
import textwrap

import numpy as np
import pytest
from scipy.sparse.csgraph import dijkstra

import fxspace as fx
from fxspace.errors import FxspaceError
from fxspace.expression import _row_workers as RW
from fxspace.expression import neighbourhood_graph, to_scipy
from fxspace.expression._paths import graph_lengths, graph_toward


@pytest.fixture
def graph():
    rng = np.random.default_rng(3)
    return neighbourhood_graph(rng.normal(size=(600, 6)), k=6, reduce_dim=None)


@pytest.fixture
def workers_on(monkeypatch):
    """Workers for every graph, however small; two processes (this one and a worker)."""
    monkeypatch.setattr(RW, "MIN_FRAMES", 0)
    monkeypatch.setenv("FXSPACE_PROCESSES", "2")
    yield
    RW._drop()


def _one_process(monkeypatch, fn):
    monkeypatch.setenv("FXSPACE_PROCESSES", "1")
    try:
        return fn()
    finally:
        monkeypatch.setenv("FXSPACE_PROCESSES", "2")


def test_rows_equal_one_process_and_scipy(graph, workers_on, monkeypatch):
    targets = np.array([5, 17, 250, 599, 0])
    d, hop = graph_toward(graph, targets)
    assert RW._CURRENT["entry"][3].size == 1  # the worker ran a share
    d1, hop1 = _one_process(monkeypatch, lambda: graph_toward(graph, targets))
    np.testing.assert_array_equal(d, d1)
    np.testing.assert_array_equal(hop, hop1)
    ref = dijkstra(to_scipy(graph), directed=False, indices=targets)
    np.testing.assert_allclose(d, ref, rtol=1e-12)
    # the hop is a next frame on a shortest path: one edge closer by its length
    f = np.arange(graph.num_frames)
    csr = to_scipy(graph).tocsr()
    for r, t in enumerate(targets):
        ok = (f != t) & (hop[r] >= 0)
        w = np.asarray(csr[f[ok], hop[r, ok]]).reshape(-1)
        np.testing.assert_allclose(d[r, ok], w + d[r, hop[r, ok]], rtol=1e-9)

    i, j = np.array([1, 1, 40, 300, 7]), np.array([2, 599, 41, 3, 7])
    np.testing.assert_array_equal(
        graph_lengths(graph, i, j), _one_process(monkeypatch, lambda: graph_lengths(graph, i, j))
    )


def test_landmark_rounds_equal_one_process(graph, workers_on, monkeypatch):
    geo = fx.farthest_point_landmarks(graph, 12, batch=4)
    one = _one_process(monkeypatch, lambda: fx.farthest_point_landmarks(graph, 12, batch=4))
    np.testing.assert_array_equal(np.asarray(geo.landmarks), np.asarray(one.landmarks))
    np.testing.assert_array_equal(np.asarray(geo.distances), np.asarray(one.distances))


def test_small_graphs_and_one_process_start_no_worker(graph, monkeypatch):
    RW._drop()
    monkeypatch.setenv("FXSPACE_PROCESSES", "2")
    graph_toward(graph, [1, 2, 3])  # 600 frames < MIN_FRAMES
    assert "entry" not in RW._CURRENT
    monkeypatch.setattr(RW, "MIN_FRAMES", 0)
    monkeypatch.setenv("FXSPACE_PROCESSES", "1")
    graph_toward(graph, [1, 2, 3])
    assert "entry" not in RW._CURRENT


def test_a_bad_setting_names_itself(graph, monkeypatch):
    monkeypatch.setattr(RW, "MIN_FRAMES", 0)
    monkeypatch.setenv("FXSPACE_PROCESSES", "two")
    with pytest.raises(FxspaceError, match="FXSPACE_PROCESSES"):
        graph_toward(graph, [1, 2])


def test_a_dead_worker_is_an_error_then_workers_start_again(graph, workers_on):
    graph_toward(graph, [1, 2])
    w = RW._CURRENT["entry"][3]
    w._procs[0].kill()
    w._procs[0].wait()
    with pytest.raises(FxspaceError, match="FXSPACE_PROCESSES=1"):
        graph_toward(graph, [1, 2, 3])
    d, _ = graph_toward(graph, [1, 2, 3])  # new workers
    assert RW._CURRENT["entry"][3] is not w and RW._CURRENT["entry"][3].size == 1
    np.testing.assert_allclose(d, dijkstra(to_scipy(graph), directed=False, indices=[1, 2, 3]))


def test_an_unguarded_script_runs_once(tmp_path):
    """The workers run their own file, not the user's ``__main__`` again (as
    multiprocessing's spawn would, unless the script guards it)."""
    script = tmp_path / "user.py"
    script.write_text(textwrap.dedent("""
        import numpy as np
        from fxspace.expression import _row_workers as RW, neighbourhood_graph
        from fxspace.expression._paths import graph_toward
        print("top level ran", flush=True)
        RW.MIN_FRAMES = 0
        g = neighbourhood_graph(np.random.default_rng(0).normal(size=(300, 4)), k=5,
                                reduce_dim=None)
        d, _ = graph_toward(g, [0, 1, 2, 3])
        print("workers", RW._CURRENT["entry"][3].size, "rows", d.shape[0], flush=True)
    """))
    env = {**os.environ, "FXSPACE_PROCESSES": "3", "FXSPACE_QUIET": "1"}
    out = subprocess.run([sys.executable, str(script)], capture_output=True, text=True,
                         env=env, timeout=120)  # fmt: skip
    assert out.returncode == 0, out.stderr
    assert out.stdout.count("top level ran") == 1
    assert "workers 2 rows 4" in out.stdout


def test_workers_inherited_by_a_fork_are_left_to_their_parent(graph, workers_on):
    """A forked child sees its parent's workers in the module: it starts its own and
    never writes to (or closes) the parent's pipes."""
    graph_toward(graph, [1, 2])
    parent = RW._CURRENT["entry"][3]
    parent.pid = -1  # as a child sees them: another process's
    try:
        d, _ = graph_toward(graph, [1, 2, 3])
        mine = RW._CURRENT["entry"][3]
        assert mine is not parent and mine.pid == os.getpid()
        assert all(p.poll() is None for p in parent._procs)  # not closed by the child
        np.testing.assert_allclose(d, dijkstra(to_scipy(graph), directed=False,
                                               indices=[1, 2, 3]))  # fmt: skip
    finally:
        parent.pid = os.getpid()
        parent.close()
