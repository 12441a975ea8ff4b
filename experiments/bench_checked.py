"""Issue 46.6: fxspace's argument checks (`checked`) against jaxtyping + beartype.

    python experiments/bench_checked.py [--repeats 50] [--rounds 9]

For two public entry points, after a warm-up (compiled), medians of rounds in which the
variants alternate (so load on a shared machine falls on each alike):

- `fx.fuzzy_cmeans` (200 points, 3 clusters) calls the dense solver that `checked` wraps;
  that solver is swapped in turn for its unwrapped self (``__wrapped__``: "bare") and for
  the unwrapped one under ``jaxtyping.jaxtyped(typechecker=beartype.beartype)``: the
  overhead of each checker on the user's call;
- `fx.solve_ik` (CesiumMan, 20 markers, one frame from rest) is not wrapped by `checked`
  (its own checks run first), so beartype's cost is measured on top of it.

Then each is called with malformed arguments, and the first line of each checker's message
and its number of lines are printed. Needs beartype (``pip install beartype``; not a
dependency of fxspace).
"""

from __future__ import annotations

import argparse
import os
import statistics
import time
from pathlib import Path

import numpy as np


def _median_s(fn, repeats: int) -> float:
    out = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        r = fn()
        import jax

        jax.block_until_ready(r)
        out.append(time.perf_counter() - t0)
    return statistics.median(out)


def _message(fn) -> tuple[str, int, str]:
    try:
        fn()
    except Exception as e:  # noqa: BLE001 - the message is what is measured
        text = str(e)
        return type(e).__name__, len(text.splitlines()), text.splitlines()[0][:160]
    return "no error", 0, ""


def _cases(fx, jnp):
    from fxspace.data import data_path

    x = jnp.asarray(np.random.default_rng(0).normal(size=(200, 2)))
    key = __import__("jax").random.key(0)
    cases = {"fuzzy_cmeans": (fx.fuzzy_cmeans, (x, 3), {"key": key}, [
        ("x is a string", ("abc", 3), {"key": key}),
        ("n_clusters is 2.5", (x, 2.5), {"key": key}),
        ("x has rank 1", (x[:, 0], 3), {"key": key}),
    ])}
    p = data_path("mesh", "CesiumMan.glb")
    if Path(p).is_file():
        mesh = fx.io.read_gltf(p)
        ms = fx.place_markers(mesh.vertices, mesh.faces, 20, seed=0)
        model = fx.ik_model(mesh, ms)
        anim = mesh.animation_names[0]
        t = np.linspace(*mesh.animation_range(anim), 3)[1:2]
        targets = fx.marker_positions(
            jnp.asarray(fx.mesh.animation_vertices(mesh, anim, t)), mesh.faces, ms)[0]
        cases["solve_ik"] = (fx.solve_ik, (model, targets), {}, [
            ("targets is a string", (model, "abc"), {}),
            ("targets has 2 columns", (model, targets[:, :2]), {}),
            ("model is a mesh", (mesh, targets), {}),
        ])
    return cases


def _variants(fx, name, fn, jaxtyped, beartype):
    """``{label: callable}`` for one entry point, plus a note: `fx.fuzzy_cmeans` calls
    `checked`'s wrapper of the dense solver, swapped here for the bare one and for the
    beartype one (the user's call, each checker in turn); `fx.solve_ik` is not wrapped by
    `checked` (its own checks run in ``_prepare``), so beartype is measured on top."""
    import fxspace.cluster._fcm as fcm

    def bear(f):
        try:
            return jaxtyped(typechecker=beartype)(f), None
        except Exception as e:  # noqa: BLE001 - beartype refuses some hints at decoration
            return None, f"{type(e).__name__}: {str(e).splitlines()[0][:120]}"

    if name == "fuzzy_cmeans":
        shipped = fcm.fuzzy_cmeans
        raw = shipped.__wrapped__
        b, err = bear(raw)

        def swapped(inner):
            def call(*a, **kw):
                fcm.fuzzy_cmeans = inner
                try:
                    return fn(*a, **kw)
                finally:
                    fcm.fuzzy_cmeans = shipped
            return call

        out = {"checked (ours)": fn, "bare": swapped(raw)}
        if b is not None:
            out["jaxtyping+beartype"] = swapped(b)
        return out, err
    b, err = bear(fn)
    out = {"own checks (ours)": fn}
    if b is not None:
        out["own checks + jaxtyping+beartype"] = b
    return out, err


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--repeats", type=int, default=50, help="calls per round (median)")
    ap.add_argument("--rounds", type=int, default=9, help="rounds, the variants alternating")
    args = ap.parse_args(argv)
    os.environ.setdefault("FXSPACE_QUIET", "1")
    import jax
    import jax.numpy as jnp

    jax.config.update("jax_enable_x64", True)
    import fxspace as fx

    try:
        from beartype import beartype
        from jaxtyping import jaxtyped
    except ImportError:
        print("beartype is not installed: pip install beartype")
        return 1
    for name, (fn, a, kw, bad) in _cases(fx, jnp).items():
        variants, bear_error = _variants(fx, name, fn, jaxtyped, beartype)
        ok = {}
        for label, f in variants.items():
            try:
                jax.block_until_ready(f(*a, **kw))
                ok[label] = f
            except Exception as e:  # noqa: BLE001
                print(f"{name}: {label}: a valid call fails: {type(e).__name__}: "
                      f"{str(e).splitlines()[0][:160]}")
        # rounds alternate the variants, so load on a shared machine falls on each alike
        per = {label: [] for label in ok}
        for _ in range(args.rounds):
            for label, f in ok.items():
                per[label].append(_median_s(lambda f=f, a=a, kw=kw: f(*a, **kw), args.repeats))
        times = {label: statistics.median(v) for label, v in per.items()}
        ref = "bare" if "bare" in times else next(iter(times))
        base = times[ref]
        for label, s in times.items():
            extra = "" if label == ref else f", {1e6 * (s - base):+.1f} us against {ref}"
            print(f"{name}: {label}: {1e3 * s:.3f} ms per call{extra}")
        if bear_error:
            print(f"{name}: jaxtyping+beartype: refused at decoration: {bear_error}")
        for what, ba, bkw in bad:
            for label, f in variants.items():
                if label == "bare":
                    continue
                kind, n, first = _message(lambda f=f, ba=ba, bkw=bkw: f(*ba, **bkw))
                print(f"{name}: {what}: {label}: {kind}, {n} line(s): {first}")
    import fxspace._validate as v

    src = Path(v.__file__).parent
    n = sum(len(p.read_text().splitlines()) for p in src.glob("_validate*.py"))
    print(f"lines of fxspace/_validate*.py: {n}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
