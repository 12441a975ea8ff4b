"""The finest level's segment test (`fxspace.navigation._segments`) against brute force:
every segment against every point, in numpy."""

from __future__ import annotations

import numpy as np
import pytest

from fxspace.navigation._segments import segments_near_points


def _brute(xy, i, j, rho):
    a, b = xy[i], xy[j]
    v = b - a
    L2 = np.maximum(np.sum(v * v, axis=1), 1e-300)
    q = xy[None, :, :]
    t = np.clip(np.sum((q - a[:, None]) * v[:, None], axis=2) / L2[:, None], 0.0, 1.0)
    d = np.linalg.norm(q - (a[:, None] + t[..., None] * v[:, None]), axis=2)
    d[np.arange(len(i)), i] = np.inf
    d[np.arange(len(i)), j] = np.inf
    return (d < rho).any(axis=1)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_matches_every_segment_against_every_point(seed):
    rng = np.random.default_rng(seed)
    # clustered points with empty space between (long clear segments exist), as an
    # embedding of a k-NN graph has
    centres = rng.uniform(-10, 10, (12, 2))
    xy = centres[rng.integers(0, 12, 1500)] + rng.normal(0, 0.6, (1500, 2))
    i = rng.integers(0, len(xy), 4000)
    j = rng.integers(0, len(xy), 4000)
    keep = i != j
    i, j = i[keep], j[keep]
    spacing = np.median(np.sort(np.linalg.norm(xy[:, None] - xy[None], axis=2), axis=1)[:, 1])
    for rho in (0.05 * spacing, 0.25 * spacing, 0.5 * spacing, 2.0 * spacing):
        got = segments_near_points(xy, i, j, rho)
        want = _brute(xy, i, j, rho)
        assert np.array_equal(got, want), (rho, int((got != want).sum()))
        assert 0 < got.sum() < len(got)  # both answers occur: the test can fail


def test_known_answers():
    xy = np.array([[0.0, 0.0], [10.0, 0.0], [5.0, 0.4], [5.0, -3.0], [20.0, 0.0]])
    i, j = np.array([0, 0, 1]), np.array([1, 3, 4])
    # 0→1 passes point 2 at 0.4; 0→3 passes nothing within 0.5; 1→4 passes nothing
    assert segments_near_points(xy, i, j, 0.5).tolist() == [True, False, False]
    # strictly closer: at exactly 0.4 the point does not block
    assert segments_near_points(xy, i, j, 0.4).tolist() == [False, False, False]


@pytest.mark.parametrize("which", ["points", "brute", "fan"])
def test_each_exact_pass_alone_matches_brute_force(which):
    from scipy.spatial import cKDTree

    from fxspace.navigation import _segments as S

    rng = np.random.default_rng(5)
    xy = rng.uniform(0, 10, (800, 2))
    i, j = rng.integers(0, 800, 3000), rng.integers(0, 800, 3000)
    keep = i != j
    i, j = i[keep], j[keep]
    rho = 0.12
    tree = cKDTree(xy)
    if which == "points":
        got = S._exact_blocks(tree, xy, i, j, rho, 0.3)
    elif which == "brute":
        got = S._brute_blocks(tree, xy, i, j, rho, 0.3)
    else:
        got = S._fan_blocks(xy, i, j, rho)
    want = _brute(xy, i, j, rho)
    assert np.array_equal(got, want) and 0 < want.sum() < len(want)


@pytest.mark.parametrize("x64", [False, True])
def test_the_float32_brute_pass_settles_near_ties_exactly(x64):
    """The brute pass runs in float32 whatever x64 says; a segment whose nearest frame is
    within float32 rounding of ρ is settled again in float64 (coordinates ~400, ρ = 0.1:
    float32 cannot tell 0.1 · (1 ± 1e-9) apart)."""
    import jax
    from scipy.spatial import cKDTree

    from fxspace.navigation import _segments as S

    rho = 0.1
    xs = np.linspace(-300.0, 300.0, 7)
    xy = np.concatenate([
        [[-400.0, 0.0], [400.0, 0.0], [-400.0, 50.0], [400.0, 50.0]],
        np.c_[xs, np.full(7, rho * (1 + 1e-9))],  # just outside ρ of segment 0 → 1
        [[0.0, 50.0 + rho * (1 - 1e-9)]],  # just inside ρ of segment 2 → 3
    ])
    i, j = np.array([0, 2, 0]), np.array([1, 3, 3])
    with jax.enable_x64(x64):
        got = S._brute_blocks(cKDTree(xy), xy, i, j, rho, 2 * rho)
    want = _brute(xy, i, j, rho)
    assert want.tolist()[:2] == [False, True]
    assert np.array_equal(got, want)


def _brute_chunked(xy, i, j, rho, chunk=4000):
    return np.concatenate([_brute(xy, i[s:s + chunk], j[s:s + chunk], rho)
                           for s in range(0, len(i), chunk)])


@pytest.mark.parametrize("seed", [0, 1])
def test_the_fan_pass_on_clusters_duplicates_and_every_rho(seed):
    """Origin by origin (`_fan_blocks`) against every pair: clustered frames, frames that
    coincide (distance 0: a frame on an end), segments all around each origin (directions
    across ±π), ρ from a twentieth of the spacing to twenty spacings."""
    from fxspace.navigation import _segments as S

    rng = np.random.default_rng(seed)
    centres = rng.uniform(-10, 10, (8, 2))
    xy = centres[rng.integers(0, 8, 600)] + rng.normal(0, 0.6, (600, 2))
    xy[:20] = xy[20:40]  # 20 frames on top of 20 others
    i = rng.integers(0, len(xy), 6000)
    j = rng.integers(0, len(xy), 6000)
    keep = i != j
    i, j = i[keep], j[keep]
    spacing = np.median(np.sort(np.linalg.norm(xy[:, None] - xy[None], axis=2), axis=1)[:, 2])
    for rho in (0.05 * spacing, 0.5 * spacing, 2.0 * spacing, 20.0 * spacing):
        got = S._fan_blocks(xy, i, j, rho)
        want = _brute_chunked(xy, i, j, rho)
        assert np.array_equal(got, want), (rho, int((got != want).sum()))
        assert 0 < want.sum() < len(want) or rho > 10 * spacing


@pytest.mark.slow
def test_an_epsilon_graphs_steps_go_by_origin_and_match_every_pair():
    """Every pair of 900 frames (404 550 segments, the regime of an ε-graph's steps) takes
    the fan pass in `segments_near_points`, and matches every segment against every frame."""
    from fxspace.navigation import _segments as S

    rng = np.random.default_rng(3)
    xy = np.cumsum(rng.normal(0, 1, (900, 2)), axis=0)  # a wandering 2-D trajectory
    i, j = np.triu_indices(len(xy), 1)
    rho = 0.3
    assert len(i) >= S._FAN_FROM * len(np.unique(i))  # the fan is chosen
    got = segments_near_points(xy, i, j, rho)
    want = _brute_chunked(xy, i, j, rho)
    assert np.array_equal(got, want) and 0 < want.sum() < len(want)


def test_whole_balls_listed_a_few_frames_at_a_time_match_brute_force(monkeypatch):
    """Where a point's nearest frames do not exhaust its ball, the whole ball is listed,
    `_BALL_ENTRIES` frames at a time (bounded memory in dense clumps): forced here with
    2 nearest and 7 frames a listing, on clustered points."""
    from scipy.spatial import cKDTree

    from fxspace.navigation import _segments as S

    monkeypatch.setattr(S, "_NEAREST", 2)
    monkeypatch.setattr(S, "_BALL_ENTRIES", 7)
    rng = np.random.default_rng(8)
    centres = rng.uniform(0, 10, (6, 2))
    xy = centres[rng.integers(0, 6, 900)] + rng.normal(0, 0.3, (900, 2))
    i, j = rng.integers(0, 900, 2500), rng.integers(0, 900, 2500)
    keep = i != j
    i, j = i[keep], j[keep]
    rho = 0.02
    got = S._exact_blocks(cKDTree(xy), xy, i, j, rho, 0.4)
    want = _brute(xy, i, j, rho)
    assert np.array_equal(got, want) and 0 < want.sum() < len(want)


@pytest.mark.parametrize("rows", [7, 1 << 15])
def test_the_compiled_near_test_is_the_pairwise_one(monkeypatch, rows):
    """`_near_rows` (the exact pass's fused test over each point's (P, k) neighbour list,
    in fixed-size calls) answers as `_near` over the flat list of pairs: missing
    neighbours (T), the segments' own ends and a last call padded past the points."""
    from fxspace.navigation import _segments as S

    monkeypatch.setattr(S, "_NEAR_ROWS", rows)
    rng = np.random.default_rng(3)
    xy = rng.normal(0, 1, (400, 2))
    i = rng.integers(0, 400, 300)
    j = (i + rng.integers(1, 400, 300)) % 400
    own = rng.integers(0, 300, 1001)  # points, each on a segment
    nb = rng.integers(0, 400, (1001, 6))
    nb[rng.random(nb.shape) < 0.3] = 400  # beyond the reach: none
    nb[:50, 0] = i[own[:50]]  # a segment's own ends are never a hit
    nb[50:100, 1] = j[own[50:100]]
    ok = nb < 400
    pair_point = np.repeat(np.arange(len(own)), 6)[ok.ravel()]
    for rho in (0.02, 0.1, 0.5):
        got = S._near_rows(xy, i, j, own, nb, rho)
        # _near over the flat pairs, each point its own "segment" (a copy of its ends)
        want = np.zeros(len(own), bool)
        want[S._near(xy, i[own], j[own], pair_point, nb[ok], rho)] = True
        assert np.array_equal(got, want), (rho, int((got != want).sum()))
        assert 0 < got.sum() < len(got)  # both answers occur


@pytest.mark.skipif(not __import__("sys").platform.startswith("linux"), reason="Linux nice")
def test_the_early_finest_test_runs_at_a_lower_priority_in_its_own_thread_only():
    """The finest level's early test (`_finest_blocks(..., background=True)`, on a thread
    of its own beside the FCM levels) lowers its own thread's priority, not the caller's
    process: the main thread's nice value is unchanged, and the answer is the same."""
    import os
    import threading

    from fxspace.expression import NeighbourGraph
    from fxspace.navigation._rho import _BACKGROUND_NICE, _finest_blocks

    rng = np.random.default_rng(0)
    x = rng.normal(size=(300, 2))
    d = np.linalg.norm(x[:, None] - x[None], axis=2)
    nb = np.argsort(d, axis=1)[:, 1:6]
    g = NeighbourGraph(nb.astype(np.int32), np.take_along_axis(d, nb, 1))
    main = os.getpriority(os.PRIO_PROCESS, threading.get_native_id())
    seen = {}

    def run():
        seen["out"] = _finest_blocks(x, g, 0.3, True)
        seen["nice"] = os.getpriority(os.PRIO_PROCESS, threading.get_native_id())

    t = threading.Thread(target=run)
    t.start()
    t.join()
    assert seen["nice"] == min(main + _BACKGROUND_NICE, 19)
    assert os.getpriority(os.PRIO_PROCESS, threading.get_native_id()) == main
    want = _finest_blocks(x, g, 0.3)
    for a, b in zip(seen["out"], want, strict=True):
        np.testing.assert_array_equal(a, b)
