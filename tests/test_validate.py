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


# --- issue 19: one validation layer ------------------------------------------------------


def test_counts_indices_keys_and_flags_refused_consistently():
    from fxspace._validate import check_bool, check_index, check_indices, check_key

    for bad in (2.5, float("nan"), float("inf"), "3", None, True):
        with pytest.raises(FxspaceError, match="n must be an integer"):
            check_int(bad, "n")
    assert check_int(3.0, "n") == 3 and check_int(np.int32(4), "n") == 4
    assert check_int(np.array(5), "n") == 5
    with pytest.raises(FxspaceError, match="frame must be an integer index, got the float"):
        check_index(2.0, "frame", 10)
    with pytest.raises(FxspaceError, match=r"frame must lie in \[0, 9\]"):
        check_index(10, "frame", 10)
    assert check_indices([0, 3], "frames", 4).dtype == np.int64
    with pytest.raises(FxspaceError, match="integer indices"):
        check_indices([0.5, 1.0], "frames", 4)
    with pytest.raises(FxspaceError, match=r"outside \[0, 3\]"):
        check_indices([0, 7], "frames", 4)
    with pytest.raises(FxspaceError, match="True or False"):
        check_bool("yes", "flag")
    check_key(jax.random.PRNGKey(0))
    check_key(jax.random.key(0))
    for bad in (0, -1, 2.5, "k", np.zeros(3)):
        with pytest.raises(FxspaceError, match=r"key must be a JAX PRNG key.*PRNGKey\(seed\)"):
            check_key(bad)
    with pytest.raises(FxspaceError, match="must be one of"):
        check_choice(np.zeros(2), "mode", ("a", "b"))  # an array is not a mode


def test_checked_reads_the_annotations():
    from typing import Literal

    from jaxtyping import Array, Float, Int

    from fxspace._validate import checked

    calls = []

    @checked
    def f(
        x: Float[Array, "n 3"],
        centers: Float[Array, "c 3"] | None = None,
        k: int = 2,
        lam: float = 1.0,
        mode: Literal["a", "b"] = "a",
        idx: Int[Array, " m"] | None = None,
        key=None,
        flag: bool = False,
    ):
        calls.append(1)
        x = jnp.asarray(x)
        return x.sum() if centers is None else (x[:, None] - centers[None]).sum()

    assert f([[1.0, 2.0, 3.0]], k=3.0) == 6.0  # a list is converted, 3.0 is the count 3
    for kwargs, match in [
        ({"x": "abc"}, "x must be a numeric array, got str"),
        ({"x": None}, "x must be a numeric array"),
        ({"x": np.zeros((2, 3), complex)}, "x is complex"),
        ({"x": np.zeros((2, 3)), "k": 2.5}, "k must be an integer, got 2.5"),
        ({"x": np.zeros((2, 3)), "lam": float("nan")}, "lam must be a finite number"),
        ({"x": np.zeros((2, 3)), "lam": "1"}, "lam must be a real number"),
        ({"x": np.zeros((2, 3)), "mode": "c"}, "mode must be one of 'a', 'b'"),
        ({"x": np.zeros((2, 3)), "idx": np.array([0.5])}, "idx must hold integers"),
        ({"x": np.zeros((2, 3)), "key": 0}, "key must be a JAX PRNG key"),
        ({"x": np.zeros((2, 3)), "flag": "yes"}, "flag must be True or False"),
        ({}, "missing a required argument: 'x'"),
    ]:
        n = len(calls)
        with pytest.raises(FxspaceError, match=match):
            f(**kwargs)
        assert len(calls) == n  # refused before the function ran
    # shapes are explained after a raw error (the function's own checks come first)
    with pytest.raises(FxspaceError, match=r"x and centers disagree on the axis 'n'|centers"):
        f(np.zeros((2, 3)), centers=np.zeros((4, 3, 2)))
    with pytest.raises(FxspaceError, match="x is empty"):
        f(np.zeros((0, 3)), centers=np.zeros((2, 4)))
    # under jit and vmap traced values pass through untouched
    assert float(jax.jit(f)(jnp.ones((2, 3)))) == 6.0
    assert jax.vmap(f)(jnp.ones((4, 2, 3))).shape == (4,)


def test_issue_examples_give_one_line_errors():
    import fxspace as fx

    X = np.random.default_rng(0).normal(size=(20, 3))
    cases = [
        (lambda: fx.fuzzy_cmeans(X, 3, key=jax.random.PRNGKey(0), n_init=2.5), "n_init"),
        (lambda: fx.fuzzy_cmeans(X, 3, key=0), "key must be a JAX PRNG key"),
        (lambda: fx.kernel_kmeans(X, 3, key=0), "key must be a JAX PRNG key"),
        (lambda: fx.kmeanspp_init(X, 3, 0), "key must be a JAX PRNG key"),
        (lambda: fx.level_sizes(100, c0=2.5), "c0 must be an integer"),
        (lambda: fx.build_hierarchy(X[:, :2], c0=2.5), "c0 must be an integer"),
        (lambda: fx.synthetic.synthetic_face(n_markers=20.5), "n_markers must be an integer"),
        (lambda: fx.synthetic.synthetic_face(seed=-1), "seed"),
        (lambda: fx.motion.sample_blend_weights(0, 3, 5), "key must be a JAX PRNG key"),
    ]
    for call, match in cases:
        with pytest.raises(FxspaceError, match=match) as e:
            call()
        assert "\n" not in str(e.value)
    S = np.arange(8.0).reshape(4, 2)
    with pytest.raises(FxspaceError, match=r"k must lie in \[1, 4\]"):
        fx.motion.knn_blend_weights(np.zeros(2), S, np.eye(4), k=0)


def test_a_wrong_object_is_named_with_its_type():
    """A raw error from an argument that is not of its annotated fxspace type becomes a
    one-line FxspaceError naming the argument and the type (``None`` only where the
    annotation allows it)."""
    from fxspace._validate import checked
    from fxspace.errors import FxspaceError
    from fxspace.navigation import Hierarchy

    @checked
    def levels_of(h: Hierarchy, k: int = 0, other: Hierarchy | None = None):
        return h.levels[k]

    with pytest.raises(FxspaceError, match="h must be a Hierarchy"):
        levels_of(3)
    with pytest.raises(FxspaceError, match="h must be a Hierarchy"):
        levels_of(None)


def test_checked_types_paths_and_directories(tmp_path):
    """Issue 33.6: an fxspace-typed argument is checked before the body, also where the
    annotation names a class imported only for type checking; a path must be a str or a
    Path; a directory given as a file is an fxspace error and an IsADirectoryError."""
    import fxspace as fx
    from fxspace.errors import FxspaceError, NotAFileError

    with pytest.raises(
        FxspaceError, match=r"mesh must be a SkinnedMesh \(fxspace.mesh\), got NoneType"
    ):
        fx.pose_vertices(None, None)
    with pytest.raises(FxspaceError, match="motion must be a Motion"):
        fx.motion.drop_root(np.zeros((3, 2)))
    with pytest.raises(FxspaceError, match=r"path must be a path \(str or pathlib.Path\), got int"):
        fx.io.read_bvh(3)
    with pytest.raises(NotAFileError, match="is a directory") as e:
        fx.io.read_bvh(tmp_path)
    assert isinstance(e.value, IsADirectoryError)
    with pytest.raises(FileNotFoundError, match="not found"):
        fx.io.read_bvh(tmp_path / "absent.bvh")


def test_a_checked_distance_matrix_is_remembered_only_for_that_array():
    """A sweep checks one JAX matrix per ε; it is checked once, and the memory never
    vouches for another array or for a stricter check."""
    import gc

    import jax.numpy as jnp
    import numpy as np

    from fxspace._validate import _DISTANCE_MATRICES, check_distance_matrix

    x = np.random.default_rng(0).normal(size=(50, 3))
    P = jnp.asarray(np.linalg.norm(x[:, None] - x[None], axis=2)).at[0, 1].set(jnp.inf)
    P = P.at[1, 0].set(jnp.inf)
    check_distance_matrix(P, "P", allow_inf=True)
    check_distance_matrix(P, "P", allow_inf=True)  # remembered
    with pytest.raises(FxspaceError, match="must be finite"):
        check_distance_matrix(P, "P")  # another check: not vouched for
    with pytest.raises(FxspaceError, match="non-negative"):
        check_distance_matrix(P.at[2, 3].set(-1.0), "P", allow_inf=True)
    n = len(_DISTANCE_MATRICES)
    del P
    gc.collect()
    assert len(_DISTANCE_MATRICES) == n - 1
