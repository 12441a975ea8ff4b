"""Dependencies are honest: every module fxspace imports at run time is declared, and the
package works with the test-only references (scipy, scikit-learn, ...) unavailable."""

from __future__ import annotations

import ast
import subprocess
import sys
import sys as _sys
import textwrap
import tomllib
from importlib import metadata
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PKG = ROOT / "fxspace"
DEV_ONLY = ("sklearn", "skfuzzy", "cvxpy", "dtaidistance", "dtw", "tslearn", "prox_tv")


def _declared() -> tuple[set[str], set[str]]:
    meta = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]
    norm = lambda s: s.split(";")[0].split("[")[0].split(">")[0].split("<")[0].split("=")[0]
    core = {norm(d).strip().lower().replace("_", "-") for d in meta["dependencies"]}
    extras = {
        norm(d).strip().lower().replace("_", "-")
        for d in meta["optional-dependencies"].get("viewer", [])
    }
    return core, extras


# modules that import an optional extra's package lazily, with a fallback where it is absent
OPTIONAL = {
    "pipelines/_sweep.py": "cluster",
    "pipelines/_dask.py": "cluster",
    "report.py": "report",  # collect(as_frame=True): pandas
    "pipelines/_search.py": "search",
    "pipelines/_search_space.py": "search",
    "pipelines/_study.py": "search",
    "pipelines/_scheduler.py": "cluster",
}


def _extra(name: str) -> set[str]:
    meta = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]
    norm = lambda s: s.split(";")[0].split("[")[0].split(">")[0].split("<")[0].split("=")[0]
    return {
        norm(d).strip().lower().replace("_", "-")
        for d in meta["optional-dependencies"].get(name, [])
    }


def _third_party_imports(path: Path) -> set[str]:
    tree = ast.parse(path.read_text(encoding="utf-8"))
    out = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            out |= {a.name.split(".")[0] for a in node.names}
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            out.add(node.module.split(".")[0])
    stdlib = set(_sys.stdlib_module_names) | {"__future__"}
    return {m for m in out if m not in stdlib and m != "fxspace"}


def test_every_runtime_import_is_declared():
    core, extras = _declared()
    dists = metadata.packages_distributions()
    problems = []
    for path in sorted(PKG.rglob("*.py")):
        allowed = core | (extras if "studio" in path.parts else set())
        rel = path.relative_to(PKG).as_posix()
        if rel in OPTIONAL:
            allowed = allowed | _extra(OPTIONAL[rel])
        for mod in _third_party_imports(path):
            names = {d.lower().replace("_", "-") for d in dists.get(mod, [mod])}
            if not names & allowed:
                problems.append(f"{path.relative_to(ROOT)} imports {mod} ({sorted(names)})")
    assert not problems, "undeclared run-time imports:\n" + "\n".join(problems)


def test_public_names_import_without_dev_dependencies():
    """A plain `pip install fxspace` has none of the test-only references: forbid fxspace's
    own modules to import them, then import every module and every public name."""
    code = textwrap.dedent(
        f"""
        import importlib, importlib.abc, pkgutil, sys
        BLOCK = {DEV_ONLY!r}
        class Block(importlib.abc.MetaPathFinder):
            # jax itself imports scipy (its own dependency); fxspace code may not
            def find_spec(self, name, path, target=None):
                if name.split(".")[0] not in BLOCK:
                    return None
                f = sys._getframe(1)
                while f is not None and f.f_globals.get("__name__", "").startswith(
                    ("importlib", "_frozen_importlib")
                ):
                    f = f.f_back
                if f is not None and f.f_globals.get("__name__", "").startswith("fxspace"):
                    raise ImportError(f"fxspace imports {{name}}, a test-only dependency")
                return None
        sys.meta_path.insert(0, Block())
        import numpy as np
        import fxspace
        n = 0
        for info in pkgutil.walk_packages(fxspace.__path__, "fxspace."):
            mod = importlib.import_module(info.name)
            for name in getattr(mod, "__all__", ()):
                getattr(mod, name)
                n += 1
        for name in dir(fxspace):
            getattr(fxspace, name)
        # the two places that used scipy at run time
        from fxspace.rotations import matrix_to_quat, quat_to_matrix
        q = np.array([0.1, 0.2, 0.3, 0.9]); q /= np.linalg.norm(q)
        assert np.allclose(matrix_to_quat(quat_to_matrix(q, order="xyzw"), order="xyzw"), q)
        print("ok", n)
        """
    )
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=ROOT)
    assert r.returncode == 0, r.stderr[-3000:]
    assert r.stdout.startswith("ok")
    assert int(r.stdout.split()[1]) > 150  # every subpackage's __all__ was walked


def test_every_declared_dependency_is_imported():
    """Issue 18: a declared run-time dependency earns its place (equinox: fxspace/results.py)."""
    core, _ = _declared()
    dists = metadata.packages_distributions()
    used: set[str] = set()
    for path in sorted(PKG.rglob("*.py")):
        for mod in _third_party_imports(path):
            used |= {d.lower().replace("_", "-") for d in dists.get(mod, [mod])}
    unused = sorted(core - used)
    assert not unused, f"declared in pyproject.toml but never imported by fxspace/: {unused}"


HEAVY = ("matplotlib", "viser", "playwright", "scipy.sparse", "scipy.sparse.csgraph")


def test_import_fxspace_loads_no_plotting_browser_or_sparse_graph_library():
    code = textwrap.dedent(
        f"""
        import sys
        import fxspace as fx
        print(sorted(m for m in {HEAVY!r} if m in sys.modules))
        # the lazy subpackages still resolve, and load their library only then
        assert callable(fx.plot.plot_sweep) and "matplotlib" in sys.modules
        assert fx.pipelines.__name__ == "fxspace.pipelines" and fx.datasets and fx.cli
        print("ok")
        """
    )
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=ROOT)
    assert r.returncode == 0, r.stderr[-3000:]
    loaded, ok = r.stdout.split("\n")[:2]
    assert loaded == "[]", f"import fxspace loaded {loaded}"
    assert ok == "ok"


NUMERICAL = ("cluster", "expression", "navigation", "controlpoints", "mesh", "motion")


def test_top_level_reexports_follow_the_stated_rule():
    """Rule 2 of fxspace/__init__.py: every non-module top-level name is the same object as
    a public name of a numerical subpackage's front, or RESULTS / an error type."""
    import importlib
    import types

    import fxspace as fx

    homes = [importlib.import_module(f"fxspace.{p}") for p in NUMERICAL]
    homes += [fx.results, fx.errors]
    stray = []
    for name in dir(fx):
        if name.startswith("_"):
            continue
        obj = getattr(fx, name)
        if isinstance(obj, types.ModuleType):
            assert obj.__name__ == f"fxspace.{name}", name
            continue
        if not any(name in getattr(h, "__all__", ()) and getattr(h, name) is obj for h in homes):
            stray.append(name)
    assert not stray, f"top-level names outside the rule: {stray}"
    assert fx.fuzzy_cmeans is fx.cluster.fuzzy_cmeans and fx.RESULTS is fx.results.RESULTS
