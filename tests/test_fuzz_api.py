"""Property-based fuzz of the public API (issue 19): bad values of each argument kind.

Every public function of ``fxspace`` (``fxspace.__all__``) and of its subpackages' fronts
whose arguments are arrays, numbers, flags, choices, counts or PRNG keys is called with
values drawn by hypothesis: well-shaped finite arrays (sizes from the jaxtyping shape in
the annotation, shared between arguments), NaN/inf, huge and tiny magnitudes, wrong
dtypes (complex, bool, string, object), wrong ranks, empty arrays, non-integer and
negative counts, strings for numbers, integer PRNG keys. Each call must either raise
`fxspace.errors.FxspaceError` or return a result that is finite wherever every input was
finite — never another exception type, never a silent inf/NaN.

Functions whose arguments are files, callables or constructed objects (meshes, graphs,
hierarchies, synthesis spaces…) are not drawn here: `SKIPPED` lists them by reason
(their own test files cover their checks); `test_skip_list_is_explicit` keeps that list
honest. The examples are bounded (derandomized, a few per function) so the whole file
runs in well under a minute.
"""

from __future__ import annotations

import dataclasses
import inspect
import math
import os
import re
import typing
import warnings

import jax
import numpy as np
import pytest
from hypothesis import HealthCheck, Phase, given, settings
from hypothesis import strategies as st

import fxspace as fx
from fxspace.errors import FxspaceError

SUBPACKAGES = (
    "cluster",
    "controlpoints",
    "expression",
    "io",
    "mesh",
    "motion",
    "navigation",
    "synthetic",
    "rotations",
    "rigid",
)

# parameter annotations naming constructed objects: a function taking one is not drawn
_OBJECT_TYPES = re.compile(
    r"\b(SkinnedMesh|MarkerSet|IKModel|Pose|LocalPose|IKForward|IKConstraints|"
    r"NormalConstraint|PlaneContact|JointLimits|JointPrior|IKRegularization|SkinTables|"
    r"Solver|Gradient|Hierarchy|Level|Route|Geodesics|NeighbourGraph|LandmarkGeodesics|"
    r"LandmarkBasis|SweepResult|ExampleSet|SynthesisSpaces|SynthState|Clocks|Motion|"
    r"RigidTransform|MarkerSequence|ControlPointModel|SceneModel|Segmentation|FaceSurface|"
    r"EditKey|FitResult|SetupData|SetupSpace|Callable|Path|dict|list|Any|KNNResult|"
    r"FCMResult|KernelKMeansResult|SparseLevel|GridIndex|NavigationSpace)\b"
)
# parameter names that hold a file, a constructed object or a free-form value
_OBJECT_NAMES = {
    "path",
    "out_dir",
    "run_dir",
    "asf_path",
    "amc_path",
    "motion",
    "geodesics",
    "graph_obj",
    "level",
    "load",
    "result",
    "value",
    "pred",
}

SKIPPED: dict[str, str] = {}  # name -> reason, filled by `_collect`


def _public_functions() -> dict[str, typing.Callable]:
    fronts = [("fx", fx)] + [(s, getattr(fx, s)) for s in SUBPACKAGES]
    out: dict[str, typing.Callable] = {}
    seen: set[int] = set()
    for label, mod in fronts:
        names = getattr(mod, "__all__", None) or [n for n in dir(mod) if not n.startswith("_")]
        for n in names:
            obj = getattr(mod, n, None)
            if obj is None or id(obj) in seen or inspect.ismodule(obj) or not callable(obj):
                continue
            seen.add(id(obj))
            if inspect.isclass(obj):
                continue  # data types are built by the functions drawn here
            out[n if label == "fx" else f"{label}.{n}"] = obj
    return out


# -- argument kinds ---------------------------------------------------------------------
def _kind(p: inspect.Parameter) -> str:
    ann = "" if p.annotation is inspect.Parameter.empty else str(p.annotation)
    if p.kind in (p.VAR_POSITIONAL, p.VAR_KEYWORD):
        return "varargs"
    if p.name == "key" or "PRNGKey" in ann:
        return "key"
    if re.search(r"\b(Float|Int|Bool|Shaped)\[", ann):
        return "array"
    if p.name in _OBJECT_NAMES or _OBJECT_TYPES.search(ann):
        return "object"
    if "Literal[" in ann:
        return "choice"
    if re.search(r"Array|ndarray", ann):
        return "array"
    if re.search(r"Sequence\[int\]|tuple\[int", ann):
        return "ints"
    if re.search(r"Sequence\[str\]|tuple\[str", ann):
        return "strs"
    if re.fullmatch(r"int( \| None)?", ann):
        return "int"
    if re.fullmatch(r"float( \| None)?|float \| int", ann):
        return "float"
    if re.fullmatch(r"bool( \| None)?", ann):
        return "bool"
    if re.fullmatch(r"str( \| None)?", ann):
        return "str"
    if not ann:
        return "array"  # an unannotated argument of a numeric API is an array
    return "other"


def _collect() -> list[str]:
    SKIPPED.clear()
    names = []
    for name, fn in _public_functions().items():
        try:
            sig = inspect.signature(fn)
        except (TypeError, ValueError):
            SKIPPED[name] = "no signature"
            continue
        kinds = {p.name: _kind(p) for p in sig.parameters.values()}
        required = {
            k: v for k, v in kinds.items() if sig.parameters[k].default is inspect.Parameter.empty
        }
        bad = sorted(k for k, v in required.items() if v in ("object", "other", "varargs"))
        if bad:
            SKIPPED[name] = f"needs constructed objects or files ({', '.join(bad)})"
            continue
        names.append(name)
    return sorted(names)


FUNCTIONS = _collect()


# -- strategies -------------------------------------------------------------------------
def _dims(ann: str) -> list[str] | None:
    m = re.search(r"\[[^,\]]+,\s*['\"]([^'\"]*)['\"]\]", ann)
    return m.group(1).split() if m else None


_FINITE = st.one_of(
    st.floats(-3, 3, allow_nan=False),
    st.sampled_from([0.0, 1.0, -1.0, 1e-25, 1e19, 250.0]),
)
_ANY = st.one_of(_FINITE, st.sampled_from([math.nan, math.inf, -math.inf]))


@st.composite
def _array(draw, ann: str, sizes: dict[str, int]):
    dims = _dims(ann)
    mode = draw(
        st.sampled_from(
            ["good"] * 6 + ["nan", "inf", "rank", "empty", "dtype", "string", "scalar", "list"]
        )
    )
    if mode == "string":
        return draw(st.sampled_from(["abc", None, b"x", {"a": 1}]))
    if mode == "scalar":
        return draw(_ANY)
    shape = []
    for d in dims or ["n", "d"]:
        if d in ("...", "*b", "*frames", "#..."):
            shape += [draw(st.integers(1, 3))] * draw(st.integers(0, 1))
        elif d.isdigit():
            shape.append(int(d))
        else:
            name = d.lstrip("*#")
            sizes.setdefault(name, draw(st.sampled_from([3, 3, 4, 1])))  # few shapes: few compiles
            shape.append(sizes[name])
    if mode == "rank":
        shape = shape[:-1] if shape and draw(st.booleans()) else shape + [2]
    if mode == "empty":
        shape = [0] + shape[1:] if shape else [0]
    integer = ann.startswith("Int[") or " Int[" in ann
    if integer:
        arr = np.random.default_rng(draw(st.integers(0, 99))).integers(-1, 5, size=shape)
        return arr if mode != "dtype" else arr + 0.5  # a fractional index
    n = int(np.prod(shape))
    vals = draw(st.lists(_FINITE, min_size=n, max_size=n)) if n <= 64 else [0.5] * n
    arr = np.asarray(vals, dtype=np.float64).reshape(shape)
    if mode in ("nan", "inf") and arr.size:
        arr.flat[draw(st.integers(0, arr.size - 1))] = math.nan if mode == "nan" else math.inf
    if mode == "dtype":
        dt = draw(st.sampled_from([np.complex64, np.bool_, np.float16, np.str_, object]))
        with warnings.catch_warnings():  # 1e19 overflows float16: that is the point
            warnings.simplefilter("ignore", RuntimeWarning)
            return arr.astype(dt)
    if mode == "list":
        return arr.tolist()
    return arr


def _strategy(p: inspect.Parameter, kind: str, sizes: dict[str, int]):
    ann = "" if p.annotation is inspect.Parameter.empty else str(p.annotation)
    optional = "None" in ann
    bad_number = st.sampled_from([math.nan, math.inf, -1.0, 2.5, "3", None, True, 1e300])
    base = {
        "array": _array(ann, sizes),
        "int": st.one_of(st.integers(-2, 6), st.integers(0, 4), bad_number),
        "float": st.one_of(_ANY, st.floats(0.01, 10), bad_number),
        "bool": st.one_of(st.booleans(), st.sampled_from(["yes", 2, None])),
        "str": st.sampled_from(["xyz", "zyx", "XYZ", "bogus", "", 3]),
        "ints": st.one_of(
            st.lists(st.integers(-1, 5), max_size=4),
            st.sampled_from([[2.5, 1], "ab", None, [0, math.nan]]),
        ),
        "strs": st.one_of(st.none(), st.sampled_from([["a", "b"], "ab", [1, 2]])),
        "key": st.sampled_from(
            [jax.random.PRNGKey(0), jax.random.key(1), 0, -1, 2.5, "key", np.zeros(3)]
        ),
    }
    if kind == "choice":
        choices = list(typing.get_args(_literal(ann)) or ())
        return st.sampled_from(choices + ["bogus", 3])
    s = base[kind]
    return st.one_of(st.none(), s) if optional else s


def _literal(ann: str):
    m = re.search(r"Literal\[([^\]]*)\]", ann)
    if not m:
        return None
    vals = [v.strip().strip("'\"") for v in m.group(1).split(",")]
    return typing.Literal[tuple(vals)]


def _leaves_finite(out) -> bool:
    leaves = jax.tree_util.tree_leaves(out)
    for leaf in leaves:
        if isinstance(leaf, float | np.floating | np.ndarray | jax.Array) and not isinstance(
            leaf, bool
        ):
            a = np.asarray(leaf)
            if a.dtype.kind in "fc" and not np.isfinite(a).all():
                return False
    return True


def _inputs_finite(kwargs) -> bool:
    for v in jax.tree_util.tree_leaves(kwargs):
        try:
            a = np.asarray(v)
        except Exception:  # noqa: BLE001 - an odd value is not a finite input
            return False
        if a.dtype.kind not in "biuf":
            return False
        if a.dtype.kind == "f" and not (np.isfinite(a).all() and np.abs(a).max(initial=0) < 1e18):
            return False
    return True


# results whose entries are inf by contract (unreachable pairs, the "no threshold" ends)
NONFINITE_OK = {
    "graph_from_dense",  # inf marks "no edge" in the padded neighbour lists
    "floyd_warshall",
    "geodesic_distances",
    "expression.floyd_warshall",
    "expression.geodesic_distances",
    "expression.next_hops",
    "next_hops",
    "connecting_threshold",
    "expression.connecting_threshold",
    "epsilon_graph",
    "expression.epsilon_graph",
}


def _pearson_undefined(kw) -> bool:
    """Pearson's r is undefined (NaN by contract) when either side is constant over the
    pairs i < j, or there are fewer than 2 pairs."""
    D = np.asarray(kw.get("D"), np.float64)
    Y = np.asarray(kw.get("embedding"), np.float64)
    iu = np.triu_indices(D.shape[0], 1)
    E = np.sqrt(((Y[:, None, :] - Y[None, :, :]) ** 2).sum(-1))[iu]
    d = D[iu]
    return d.size < 2 or np.ptp(d) <= 1e-12 * np.abs(d).max() or np.ptp(E) <= 1e-6 * E.max()


# name -> predicate on the arguments: when it holds, a NaN result is the documented answer
NAN_BY_CONTRACT = {"pearson_score": _pearson_undefined}

# Findings of this fuzz not fixed yet (issue 19, left to the owners of these functions):
# name -> the raw exception type a bad argument still raises (or "returned" NaN/inf from
# finite input). Each is an expected failure (xfail, not strict); remove a name once its
# function checks its arguments (e.g. with `fxspace._validate.checked`).
KNOWN: dict[str, str] = {}


def _call(name: str, fn, kwargs):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        try:
            out = fn(**kwargs)
        except FxspaceError:
            return None
        except Exception as e:  # noqa: BLE001 - the property under test
            shown = {k: _short(v) for k, v in kwargs.items()}
            raise AssertionError(
                f"{name}({shown}) raised {type(e).__name__}: {str(e)[:300]}"
            ) from e
    if name not in NONFINITE_OK and _inputs_finite(kwargs) and not _leaves_finite(out):
        if name in NAN_BY_CONTRACT and NAN_BY_CONTRACT[name](kwargs):
            return out
        if not _flags_failure(out):
            shown = {k: _short(v) for k, v in kwargs.items()}
            raise AssertionError(f"{name}({shown}) returned NaN/inf from finite input")
    return out


def _flags_failure(out) -> bool:
    """A result carrying a non-successful `RESULTS` code reports its own failure."""
    res = getattr(out, "result", None)
    if res is None:
        return False
    try:
        return not bool(fx.results.is_successful(res))
    except Exception:  # noqa: BLE001
        return False


def _short(v):
    if isinstance(v, np.ndarray | jax.Array):
        return f"array{tuple(v.shape)}:{v.dtype}"
    r = repr(v)
    return r if len(r) < 40 else r[:37] + "..."


@pytest.mark.parametrize("name", FUNCTIONS)
def test_public_function_fails_cleanly(name):
    fn = _public_functions()[name]
    if name in KNOWN and not os.environ.get("FXSPACE_FUZZ_ALL"):  # =1: see the findings
        pytest.xfail(f"{fn.__module__}.{fn.__name__}: bad input still gives {KNOWN[name]}")
    sig = inspect.signature(fn)
    params = [p for p in sig.parameters.values() if _kind(p) not in ("object", "other")]

    @settings(
        max_examples=int(os.environ.get("FXSPACE_FUZZ_EXAMPLES", "3")),  # more: a deeper walk
        derandomize=True,
        phases=[Phase.explicit, Phase.generate],  # no shrinking: each shrink step compiles
        report_multiple_bugs=False,
        deadline=None,
        database=None,
        suppress_health_check=list(HealthCheck),
    )
    @given(data=st.data())
    def check(data):
        sizes: dict[str, int] = {}
        kwargs = {}
        for p in params:
            if p.default is not inspect.Parameter.empty and data.draw(st.booleans()):
                continue  # leave some defaults in place
            kwargs[p.name] = data.draw(_strategy(p, _kind(p), sizes), label=p.name)
        _call(name, fn, kwargs)

    check()


def test_skip_list_is_explicit():
    """Every public function is either drawn or skipped with a reason."""
    everything = set(_public_functions())
    assert everything == set(FUNCTIONS) | set(SKIPPED)
    assert all(SKIPPED.values())
    assert len(FUNCTIONS) > 60  # the walk reaches most of the numeric API


@pytest.mark.parametrize(
    "call",
    [
        lambda: fx.io.MarkerSequence(np.zeros((2, 2, 3)), ("a", "b"), math.nan),
        lambda: fx.io.MarkerSequence(np.zeros((2, 2, 3)), ("a", "b"), "60"),
        lambda: fx.io.MarkerSequence(np.zeros((2, 2, 3), complex), ("a", "b"), 60.0),
        lambda: fx.io.MarkerSequence(np.zeros((2, 2, 3)), ("a", "b"), 60.0).slice(0, 2, 2.5),
        lambda: fx.io.MarkerSequence(np.zeros((2, 2, 3)), ("a", "b"), 60.0).to_units(3),
        lambda: fx.synthetic.synthetic_face(n_markers=2.5),
        lambda: fx.synthetic.synthetic_face(seed=-1),
        lambda: fx.synthetic.synthetic_face(n_frames="10"),
    ],
)
def test_data_types_and_generators_refuse_bad_values(call):
    with pytest.raises(FxspaceError):
        call()


# -- decisions on the findings above (issue 19), each checked against a known answer -----
def test_quat_normalize_refuses_nonpositive_eps_and_keeps_zero_finite():
    for eps in (0.0, -1.0, math.nan):
        with pytest.raises(FxspaceError, match="eps"):
            fx.rotations.quat_normalize(np.zeros(4), eps=eps)
    np.testing.assert_array_equal(fx.rotations.quat_normalize(np.zeros(4)), np.zeros(4))
    np.testing.assert_allclose(fx.rotations.quat_normalize(np.array([2.0, 0, 0, 0])), [1, 0, 0, 0])
    with pytest.raises(FxspaceError, match=r"\(\.\.\., 4\)"):
        fx.rotations.quat_normalize(np.ones(3))


def test_pearson_score_constant_side_is_nan_and_scale_free():
    from scipy.spatial.distance import pdist, squareform
    from scipy.stats import pearsonr

    rng = np.random.default_rng(0)
    Y = rng.standard_normal((6, 2))
    D = squareform(pdist(Y + 0.1 * rng.standard_normal((6, 2))))
    ref = pearsonr(squareform(D, checks=False), pdist(Y)).statistic
    # float32 at 1e-25 / 1e18: scaled before squaring, so the same r (no underflow/overflow)
    for s in (1e-25, 1.0, 1e18):
        r = fx.pearson_score(np.float32(D * s), np.float32(Y * s))
        np.testing.assert_allclose(float(r), ref, rtol=1e-4)
    # undefined (documented NaN): a constant D, a collapsed embedding
    assert np.isnan(fx.pearson_score(np.ones((4, 4)) - np.eye(4), rng.standard_normal((4, 2))))
    assert np.isnan(fx.pearson_score(D, np.zeros((6, 2))))
    with pytest.raises(FxspaceError, match="embedding"):
        fx.pearson_score(D, np.zeros((5, 2)))


def test_plain_value_errors_became_fxspace_errors():
    with pytest.raises(FxspaceError, match="at least 3"):
        fx.absolute_orientation(np.zeros((2, 3)), np.zeros((2, 3)))
    with pytest.raises(ValueError, match=r"\(k, 3\)"):  # old `except ValueError` still works
        fx.absolute_orientation(np.zeros((4, 3)), np.zeros((5, 3)))
    key = jax.random.PRNGKey(0)
    with pytest.raises(FxspaceError, match="max_active"):
        fx.motion.sample_blend_weights(key, 3, 5, max_active=0)
    with pytest.raises(FxspaceError, match="concentration"):
        fx.motion.sample_blend_weights(key, 3, 5, concentration=math.nan)
    with pytest.raises(FxspaceError, match="signal"):
        fx.motion.find_key_times(np.zeros((3, 3)), 1, 2)


def test_absolute_orientation_float32_extreme_scales():
    """Scaled before the products: the same rotation at 1e-25 and 1e18 as at 1."""
    from scipy.spatial.transform import Rotation

    rng = np.random.default_rng(1)
    R = Rotation.from_rotvec([0.3, -0.2, 0.5]).as_matrix()
    src = rng.standard_normal((8, 3))
    dst = src @ R.T
    for s in (1e-25, 1e18):
        tf = fx.absolute_orientation(np.float32(src * s), np.float32(dst * s))
        np.testing.assert_allclose(np.asarray(tf.R), R, atol=1e-4)


def test_dtw_cost_matrix_and_median_gamma_float32_extreme_scales():
    from scipy.spatial.distance import cdist, pdist

    rng = np.random.default_rng(2)
    a, b = rng.standard_normal((5, 2)), rng.standard_normal((4, 2))
    for s in (1e-12, 1e15):  # float32: the squared results stay in range, the products not
        c = fx.motion.dtw_cost_matrix(np.float32(a * s), np.float32(b * s))
        np.testing.assert_allclose(np.asarray(c) / s**2, cdist(a, b, "sqeuclidean"), rtol=1e-4)
    X = rng.standard_normal((9, 3))
    ref = 1.0 / np.median(pdist(X, "sqeuclidean"))
    for s in (1e-15, 1e15):
        g = fx.median_gamma(np.float32(X * s))
        np.testing.assert_allclose(float(g) * s**2, ref, rtol=1e-4)
    with pytest.raises(FxspaceError):  # γ ≈ 1e50 is not a float32
        fx.median_gamma(np.float32(X * 1e-25))


def test_nan_in_nan_out_where_results_are_arrays():
    key = jax.random.PRNGKey(0)
    x = np.random.default_rng(3).standard_normal((6, 2))
    x[2, 1] = math.nan
    out = fx.kmeanspp_extend(x, x[:2], 2, key)
    assert np.isnan(np.asarray(out)).all()  # no plausible centres from a NaN point
    P = np.random.default_rng(4).standard_normal((5, 4, 3))
    P[1, 0, 0] = math.nan
    al = fx.navigation.rigid_align(P, P[0])
    assert np.isnan(al[1]).all() and np.isfinite(al[[0, 2, 3, 4]]).all()


# -- the wrong-type family over every public name -----------------------------------------
WRONG_TYPES = {"None": None, "int": 3, "str": "x", "object": object()}
# every required argument of these takes a plain number: 3 is a right answer, not a wrong
# type (a frame count, a joint count, a 0-d frame or control value, a window centre)
INT_IS_VALID = {
    "cluster.pad_rows", "level_sizes", "linear_interpolation", "motion.smooth_controls",
    "rest_pose", "temporal_window",
}  # fmt: skip
_KNOWN_FILE = os.path.join(os.path.dirname(__file__), "fuzz_wrong_type_known.txt")


def _wrong_type_failures() -> dict[str, list[str]]:
    """``{name: [family → what happened]}`` for every public function that, called with
    a wrong-type value as every required positional argument, does anything but raise
    `FxspaceError` (a raw exception, or accepting it)."""
    out: dict[str, list[str]] = {}
    for name, fn in sorted(_public_functions().items()):
        try:
            sig = inspect.signature(fn)
        except (TypeError, ValueError):
            continue
        req = [
            p for p in sig.parameters.values()
            if p.default is inspect.Parameter.empty
            and p.kind in (p.POSITIONAL_ONLY, p.POSITIONAL_OR_KEYWORD)
        ]  # fmt: skip
        if not req:
            continue
        for label, v in WRONG_TYPES.items():
            if label == "int" and name in INT_IS_VALID:
                continue
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                try:
                    fn(*[v] * len(req))
                    what = "accepted"
                except FxspaceError:
                    continue
                except Exception as e:  # noqa: BLE001 - what the walk reports
                    what = type(e).__name__
            out.setdefault(name, []).append(f"{label}→{what}")
    return out


def test_wrong_type_family_coverage_is_printed_and_never_regresses(tmp_path, monkeypatch):
    """Issue 33.6: the walk's coverage (functions × argument families), printed. The
    drawn families (NaN/inf, huge/tiny, wrong dtype and rank, empty, non-integer and
    negative counts, strings for numbers, integer keys) reach ``FUNCTIONS``; the
    wrong-type family (None, an int, a string, an object for every required argument)
    reaches every public name. The names that still answer it with a raw error are
    listed in ``tests/fuzz_wrong_type_known.txt``: none may be added (a name that now
    refuses cleanly is printed, to be taken off the list)."""
    monkeypatch.chdir(tmp_path)  # a writer handed "x" writes here, never into the checkout
    everything = _public_functions()
    bad = _wrong_type_failures()
    known = set()
    if os.path.exists(_KNOWN_FILE):
        with open(_KNOWN_FILE) as f:
            known = {ln.strip() for ln in f if ln.strip() and not ln.startswith("#")}
    print(
        f"\nfuzz coverage: {len(everything)} public functions; drawn families "
        f"(NaN/inf, huge/tiny, dtype, rank, empty, counts, strings, keys): {len(FUNCTIONS)}; "
        f"skipped from the drawn families (objects/files): {len(SKIPPED)}; wrong-type "
        f"family: {len(everything) - len(bad)} refuse cleanly, {len(bad)} known raw"
    )
    new = sorted(set(bad) - known)
    assert not new, "raw errors for wrong-type arguments:\n" + "\n".join(
        f"{n}: {', '.join(bad[n])}" for n in new
    )
    fixed = sorted(known - set(bad))
    if fixed:  # may depend on the data root being there: reported, not failed
        print(f"now refuse cleanly (take them off {_KNOWN_FILE}): {fixed}")


@pytest.mark.parametrize(
    ("call", "match"),
    [
        (lambda: fx.motion.quat_conj(3.0), "q must be"),
        (lambda: fx.rotations.quat_from_axis_angle(3.0, 1.0), "axis must be"),
        (lambda: fx.reconstruction_error(3.0, 3.0), "X must be"),
        (lambda: fx.navigation.link_pairs(None), "no links"),
        (lambda: fx.navigation.link_pairs(np.ones((2, 3), bool)), "links must be"),
        (lambda: fx.navigation.hierarchy_from_arrays(3), "hierarchy_to_arrays"),
        (lambda: fx.frame_path(object(), [0, 1]), "paths"),
        (lambda: fx.motion.register_dtw("x"), "features"),
        (lambda: fx.motion.register_dtw([np.zeros((4, 2)), np.zeros((3, 3))]), "share"),
        (lambda: fx.motion.control_defaults(None, {}), "setup"),
        (lambda: fx.controlpoints.effective_keys("x"), "keys"),
        (lambda: fx.controlpoints.effective_keys([3]), r"keys\[0\]"),
        (lambda: fx.controlpoints.choose_count("x", []), "Z"),
        (lambda: fx.controlpoints.character("x", "x", "x"), "vertices"),
        (lambda: fx.controlpoints.head_model("x"), "rest_markers"),
        (lambda: fx.io.write_obj_sequence("out", "x", "x"), "vertices"),
    ],
)
def test_wrong_types_refused_by_name(call, match, tmp_path, monkeypatch):
    """Issue 33.6: the last names of the wrong-type family, each refused with the argument
    named (they answered with a raw error, or accepted a scalar where a shape is needed)."""
    monkeypatch.chdir(tmp_path)
    with pytest.raises(FxspaceError, match=match):
        call()
    assert not any(tmp_path.iterdir())  # nothing written on the way


def test_effective_keys_reads_a_generator_once():
    k = fx.controlpoints.EditKey(segment=0, control=1, frame=3, offset=(0.0, 1.0, 0.0))
    out = fx.controlpoints.effective_keys(x for x in [k])
    assert out == {(0, 1): [k]}


# ------------------------------------------------ issue 43: the file and folder families
_RUN_NAMES = ("status.json", "metrics.json", "meta.json", "config.toml", ".fxspace-lock",
              ".fxspace-manifest", "cache", "cache/KEY", "cache/space.npz",
              "expression_space.npz")  # fmt: skip
_FILE_FAMILIES = ("symlink_out", "fifo", "garbage_json", "torn", "read_only", "folder")


@pytest.mark.slow  # ~8 s on 2 cores; each family's case runs fast in test_issue43_files
@settings(max_examples=24, deadline=None, derandomize=True, phases=[Phase.generate],
          suppress_health_check=list(HealthCheck))  # fmt: skip
@given(family=st.sampled_from(_FILE_FAMILIES), name=st.sampled_from(_RUN_NAMES),
       finished=st.booleans(), force=st.booleans())  # fmt: skip
def test_run_folder_file_families(tmp_path_factory, family, name, finished, force):
    """Issue 43: a run folder whose bookkeeping name is a symlink out of it, a FIFO,
    garbage JSON, a torn archive, a folder, or a read-only run folder: the run completes
    or fails with one `FxspaceError`, within seconds, and nothing outside the folder
    changes (the victim's files keep their bytes)."""
    import shutil
    import signal
    import types
    from unittest import mock

    from fxspace.pipelines import _REGISTERED, register, run_dict
    from fxspace.runs import cached_arrays, save_npz_atomic

    tmp = tmp_path_factory.mktemp("files")
    victim = tmp / "victim"
    victim.mkdir()
    (victim / "KEY").write_text("the user's")
    (victim / "notes.txt").write_text("the user's")
    before = {p.name: p.read_bytes() for p in victim.iterdir()}
    mod = types.ModuleType("fuzz_files_toy")
    mod.Config, mod.STAGES = _FuzzCfg, ("space",)
    mod.run = lambda cfg, d, seed: (
        save_npz_atomic(d / "expression_space.npz",
                        **cached_arrays(d, "space", lambda: {"x": np.arange(3)})),
        {"ok": 1},
    )[1]  # fmt: skip
    register(mod, "fuzz_files_toy")
    r = tmp / "r"
    # (git is slow on 2 cores) where write_meta reads it (fxspace.runs re-exports it)
    patch = mock.patch("fxspace._run_folder.git_sha", lambda: None)
    patch.start()
    try:
        if finished:
            run_dict({"experiment": "fuzz_files_toy"}, r)
        r.mkdir(exist_ok=True)
        p = r / name
        p.parent.mkdir(exist_ok=True)
        if family != "read_only" and (p.exists() or p.is_symlink()):
            shutil.rmtree(p) if p.is_dir() and not p.is_symlink() else p.unlink()
        if family == "symlink_out":
            p.symlink_to(victim if name == "cache" else victim / "notes.txt")
            if name != ".fxspace-manifest":
                with (r / ".fxspace-manifest").open("a") as f:
                    f.write(f"{name}\n")
        elif family == "fifo":
            os.mkfifo(p)
        elif family == "garbage_json":
            p.write_bytes(b'{"garbage\xff')
        elif family == "torn":
            p.write_bytes(b"PK\x03\x04\x14\x00")
        elif family == "folder":
            p.mkdir()
            (p / "inside.txt").write_text("the user's")
        elif family == "read_only":
            r.chmod(0o500)

        def boom(*_):
            raise TimeoutError(f"{family} at {name} blocked")

        old = signal.signal(signal.SIGALRM, boom)
        signal.alarm(30)
        try:
            run_dict({"experiment": "fuzz_files_toy"}, r, force=force)
            assert (r / "metrics.json").is_file()
        except FxspaceError:
            pass
        finally:
            signal.alarm(0)
            signal.signal(signal.SIGALRM, old)
            r.chmod(0o700)
    finally:
        patch.stop()
        _REGISTERED.pop("fuzz_files_toy", None)
    assert {p.name: p.read_bytes() for p in victim.iterdir()} == before
    if family == "folder":
        assert (p / "inside.txt").read_text() == "the user's"


@dataclasses.dataclass(frozen=True)
class _FuzzCfg:
    def validate(self):
        pass


# ------------------------------------------------ issue 43: the face solve's bad bindings
_FACE_FAMILIES = ("units", "permuted", "swapped", "outlier", "degenerate", "duplicate")


def _face_case():
    """A small rig (a bumpy 10 × 10 sheet, 4 named shapes), markers at every other
    vertex, a clean 8-frame take: built once."""
    if not hasattr(_face_case, "cached"):
        rng = np.random.default_rng(0)
        u, v = np.meshgrid(np.linspace(-1, 1, 10), np.linspace(-1, 1, 10))
        V = np.stack([u.ravel(), v.ravel(), 0.3 * np.exp(-(u**2 + v**2)).ravel()], 1) * 10
        cells = [(i * 10 + j, i * 10 + j + 1, (i + 1) * 10 + j + 1, (i + 1) * 10 + j)
                 for i in range(9) for j in range(9)]  # fmt: skip
        F = [(a, b, c) for a, b, c, _ in cells] + [(a, c, d) for a, _, c, d in cells]
        D = [np.exp(-((u.ravel() - c[0]) ** 2 + (v.ravel() - c[1]) ** 2) / 0.15)[:, None]
             * rng.normal(0, 2.0, 3)[None] for c in rng.uniform(-0.7, 0.7, (4, 2))]  # fmt: skip
        rig = fx.face.rig_from_arrays(V, np.asarray(D), [f"s{k}" for k in range(4)], np.asarray(F))
        ids = np.arange(0, 100, 2)
        W = rng.uniform(0, 1, (8, 4))
        X = np.asarray(rig.shape_vertices(W))[:, ids] + rng.normal(0, 0.02, (8, len(ids), 3))
        b = fx.face.bind_markers(rig, vertex_ids=ids)
        assert bool(np.all(np.asarray(fx.face.solve_weights(rig, b, X).converged)))  # clean
        _face_case.cached = rig, ids, X, b
    return _face_case.cached


@pytest.mark.slow  # ~25 s on 2 busy cores; each family's case runs fast in test_issue43_face
@settings(max_examples=18, deadline=None, derandomize=True, phases=[Phase.generate],
          suppress_health_check=list(HealthCheck))  # fmt: skip
@given(family=st.sampled_from(_FACE_FAMILIES), k=st.integers(0, 10_000))
def test_face_solve_bad_binding_family(family, k):
    """Issue 43.2: a face take that does not fit its binding — other units, markers in
    another order or two swapped, one marker far off in one frame, a degenerate or
    duplicated binding — is refused with one `FxspaceError`, or the frames it spoils are
    not ``successful`` (never "converged" on garbage); the clean take is."""
    rig, ids, X, b = _face_case()
    rng = np.random.default_rng(k)
    Y, bad = X.copy(), np.ones(len(X), bool)
    if family == "degenerate":
        pts = np.ones((len(ids), 3)) if k % 2 else np.c_[np.arange(len(ids)), 0 * ids, 0 * ids]
        with pytest.raises(FxspaceError, match="degenerate"):
            fx.face.bind_markers(rig, pts * 1.0, [f"m{i}" for i in range(len(ids))])
        return
    if family == "duplicate":
        names = [f"m{i}" for i in range(len(ids))]
        names[int(rng.integers(1, len(ids)))] = "m0"
        with pytest.raises(FxspaceError, match="repeated"):
            fx.face.bind_markers(rig, vertex_ids=ids, names=names)
        return
    if family == "units":
        factor = float(rng.choice([1e-3, 1e-2, 0.1, 1 / 25.4, 10.0, 25.4, 100.0, 1000.0]))
        with pytest.raises(FxspaceError, match="the size of the neutral frame"):
            fx.face.solve_weights(rig, b, X * factor)
        return
    if family == "permuted":
        perm = rng.permutation(len(ids))
        while np.sum(perm != np.arange(len(ids))) < 4:
            perm = rng.permutation(len(ids))
        Y = X[:, perm]
    elif family == "swapped":
        i, j = rng.choice(len(ids), 2, replace=False)
        while np.linalg.norm(X[0, i] - X[0, j]) < 3.0:  # two markers apart on the face
            i, j = rng.choice(len(ids), 2, replace=False)
        Y[:, [i, j]] = Y[:, [j, i]]
    elif family == "outlier":
        t, m = int(rng.integers(len(X))), int(rng.integers(len(ids)))
        d = rng.normal(size=3)
        Y[t, m] += d / np.linalg.norm(d) * rng.uniform(1.0, 50.0) * b.size  # 1–50 faces off
        bad[:] = False
        bad[t] = True
    s = fx.face.solve_weights(rig, b, Y)
    ok = np.asarray(s.converged)
    assert not ok[bad].any() and s.notes, (family, k)
