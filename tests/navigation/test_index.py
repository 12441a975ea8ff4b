"""The grid index behind pad clicks, against scipy's k-d tree, and the links module split."""

import numpy as np
import pytest
from scipy.spatial import cKDTree

import fxspace as fx
from fxspace.navigation import GridIndex


@pytest.mark.parametrize("n", [1, 2, 7, 150, 2400])
def test_nearest_matches_kdtree(n, rng):
    P = rng.normal(size=(n, 2)) * [4.0, 0.7]  # anisotropic, like an MDS plane
    Q = np.concatenate([rng.normal(size=(300, 2)) * 5, P[: min(n, 20)] + 1e-9])
    idx = GridIndex(P)
    got = np.array([idx.nearest_index(q) for q in Q])
    d_ref, _ = cKDTree(P).query(Q)
    d_got = np.linalg.norm(P[got] - Q, axis=1)
    np.testing.assert_allclose(d_got, d_ref, rtol=0, atol=1e-12)


def test_ids_duplicates_and_errors():
    P = np.array([[0.0, 0.0], [0.0, 0.0], [3.0, 1.0]])
    idx = GridIndex(P, ids=np.array([10, 11, 12]))
    assert idx.nearest([0.1, 0.0]) == 10  # a tie goes to the lower row
    assert idx.nearest([2.9, 1.2]) == 12
    with pytest.raises(fx.FxspaceError, match="points"):
        GridIndex(np.zeros((0, 2)))
    with pytest.raises(fx.FxspaceError, match="finite"):
        GridIndex(np.array([[np.nan, 0.0]]))


def test_public_names_are_the_one_implementation():
    """Issue 45: one implementation behind each public name (no dense/sparse front)."""
    from fxspace.navigation import _level, _links

    assert fx.center_links is fx.navigation.center_links is _links.center_links
    assert fx.link_graph_connected is _level.link_graph_connected
    assert fx.navigation.SparseLevel is fx.navigation.Level
