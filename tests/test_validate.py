"""The one shared validation helper (fxspace._validate): dtype policy, shapes, non-finite
values, scalars, missing-marker reports."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from fxspace._validate import (
    as_float_array,
    check_choice,
    check_int,
    check_readable,
    check_scalar,
    describe_missing,
    missing_report,
)
from fxspace.errors import FxspaceError


def test_dtype_policy():
    assert as_float_array(np.ones(3, np.float32), "x").dtype == jnp.float32
    assert as_float_array(np.ones(3, np.float64), "x").dtype == jnp.float64  # x64 in tests
    assert as_float_array(np.arange(3), "x").dtype.kind == "f"
    assert as_float_array([True, False], "x", xp="numpy").dtype.kind == "f"
    for bad, word in [
        (np.ones(3, np.complex128), "complex"),
        (np.ones(3, np.float16), "float16"),
        (np.array(["a"]), "numeric"),
        ("abc", "numeric"),
    ]:
        with pytest.raises(FxspaceError, match=f"points.*{word}|{word}.*points"):
            as_float_array(bad, "points")


def test_shapes_and_frames():
    with pytest.raises(FxspaceError, match="empty"):
        as_float_array(np.zeros((0, 3)), "x")
    with pytest.raises(FxspaceError, match="1 frame"):
        as_float_array(np.zeros((1, 3)), "x", min_frames=2)
    with pytest.raises(FxspaceError, match=r"\(n_points, n_features\)"):
        as_float_array(np.zeros(3), "X", axes=("n_points", "n_features"))
    with pytest.raises(FxspaceError, match="size 3 on axis 2"):
        as_float_array(np.zeros((2, 2, 2)), "p", shape=(None, None, 3))


def test_non_finite_policies():
    x = np.array([[1.0, np.nan], [np.inf, 2.0]])
    with pytest.raises(FxspaceError, match=r"2 entries, at \(0, 1\), \(1, 0\)"):
        as_float_array(x, "x")
    with pytest.raises(FxspaceError, match="±inf"):
        as_float_array(x, "x", finite="nan")
    y = as_float_array(np.array([1.0, np.nan]), "x", finite="nan")
    assert np.isnan(np.asarray(y)[1])
    assert as_float_array(x, "x", finite="allow").shape == (2, 2)
    # traced values are not value-checked (the result reports it instead)
    jax.jit(lambda a: as_float_array(a, "x"))(jnp.asarray(x))


def test_scalars():
    assert check_scalar(2, "m", low=1.0, low_open=True) == 2.0
    for v in (float("nan"), float("inf"), 1j, "1", True, np.ones(2)):
        with pytest.raises(FxspaceError, match="lam"):
            check_scalar(v, "lam")
    with pytest.raises(FxspaceError, match="gamma must be > 0"):
        check_scalar(0.0, "gamma", low=0.0, low_open=True)
    with pytest.raises(FxspaceError, match=r"q must lie in \(0, 1\]"):
        check_scalar(1.5, "q", low=0.0, high=1.0, low_open=True)
    assert check_int(np.int64(3), "n", low=0) == 3
    with pytest.raises(FxspaceError, match="seed must be >= 0"):
        check_int(-1, "seed", low=0)
    with pytest.raises(FxspaceError, match="integer"):
        check_int(1.5, "n")
    with pytest.raises(FxspaceError, match="'a', 'b'"):
        check_choice("c", "mode", ("a", "b"))


def test_missing_report_runs():
    p = np.zeros((10, 3, 3))
    p[2:5, 1] = np.nan
    p[7, 2, 0] = np.nan
    p[9, 1] = np.nan
    runs = missing_report(p, ["a", "b", "c"])
    assert runs == [("b", 2, 4), ("b", 9, 9), ("c", 7, 7)]
    assert describe_missing(runs) == "b frames 2–4; b frame 9; c frame 7"


def test_check_readable(tmp_path):
    with pytest.raises(IsADirectoryError, match="is a directory"):
        check_readable(tmp_path, "marker file")
    with pytest.raises(FileNotFoundError, match="marker file not found"):
        check_readable(tmp_path / "x", "marker file")
    f = tmp_path / "f"
    f.write_text("x")
    assert check_readable(f) == f
