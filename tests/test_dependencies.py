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
