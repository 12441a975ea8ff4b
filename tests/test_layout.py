"""Issues 18, 29 and 46: the package stays readable — no function in fxspace/ longer than
100 lines, no module longer than 500 (the architecture page reads both limits here), and
no private name imported inside a function from another module."""

from __future__ import annotations

import ast
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PKG = ROOT / "fxspace"
MAX_LINES = 100
MAX_MODULE_LINES = 500


def long_functions(root: Path = PKG, limit: int = MAX_LINES) -> list[str]:
    """``path:line name (N lines)`` for every function or method longer than ``limit``
    lines (decorators excluded, docstring included), nested ones counted on their own."""
    out = []
    for path in sorted(root.rglob("*.py")):
        tree = ast.parse(path.read_text(encoding="utf-8"), filename=str(path))
        for node in ast.walk(tree):
            if isinstance(node, ast.FunctionDef | ast.AsyncFunctionDef):
                n = node.end_lineno - node.lineno + 1
                if n > limit:
                    rel = path.relative_to(root.parent)
                    out.append(f"{rel}:{node.lineno} {node.name} ({n} lines)")
    return out


def test_no_function_over_100_lines():
    found = long_functions()
    assert not found, f"functions over {MAX_LINES} lines:\n" + "\n".join(found)


def test_the_walk_sees_long_functions(tmp_path):
    body = "\n".join(f"    x{i} = {i}" for i in range(MAX_LINES))
    (tmp_path / "m.py").write_text(f"def short():\n    return 1\n\n\ndef long():\n{body}\n")
    assert [s.split()[1] for s in long_functions(tmp_path)] == ["long"]


def long_modules(root: Path = PKG, limit: int = MAX_MODULE_LINES) -> dict[str, int]:
    """``{path: lines}`` for every module under ``root`` longer than ``limit`` lines."""
    out = {}
    for path in sorted(root.rglob("*.py")):
        n = len(path.read_text(encoding="utf-8").splitlines())
        if n > limit:
            out[path.relative_to(root.parent).as_posix()] = n
    return out


def test_no_module_over_500_lines():
    found = long_modules()
    assert not found, f"modules over {MAX_MODULE_LINES} lines (split them by job): {found}"


def test_the_walk_sees_long_modules(tmp_path):
    (tmp_path / "short.py").write_text("x = 1\n")
    (tmp_path / "long.py").write_text("x = 1\n" * (MAX_MODULE_LINES + 1))
    assert long_modules(tmp_path) == {f"{tmp_path.name}/long.py": MAX_MODULE_LINES + 1}


def private_imports_in_functions(root: Path = PKG) -> list[str]:
    """``path:line`` for every import inside a function of a private name from another
    module of the package (a private module such as ``fxspace._x`` / ``fxspace.y._z``,
    or a ``_name``): such an import hides a dependency, often a cycle, from the drawing."""
    out = []
    for path in sorted(root.rglob("*.py")):
        tree = ast.parse(path.read_text(encoding="utf-8"), filename=str(path))
        for fn in ast.walk(tree):
            if not isinstance(fn, ast.FunctionDef | ast.AsyncFunctionDef):
                continue
            for node in ast.walk(fn):
                if isinstance(node, ast.ImportFrom) and (node.level or (node.module or "")
                                                         .startswith(root.name)):
                    parts = (node.module or "").split(".")
                    if any(q.startswith("_") for q in parts) or any(
                            a.name.startswith("_") for a in node.names):
                        out.append(f"{path.relative_to(root.parent)}:{node.lineno}")
                elif isinstance(node, ast.Import):
                    out += [f"{path.relative_to(root.parent)}:{node.lineno}" for a in node.names
                            if a.name.startswith(root.name + ".") and any(
                                q.startswith("_") for q in a.name.split("."))]
    return out


def test_no_function_level_import_of_a_private_name():
    found = private_imports_in_functions()
    assert not found, "imports of private names inside functions (import at the top):\n" + (
        "\n".join(found))


def test_the_walk_sees_private_imports_in_functions(tmp_path):
    pkg = tmp_path / "fxspace"
    pkg.mkdir()
    (pkg / "a.py").write_text(
        "from fxspace._b import x\n\n\ndef f():\n    from fxspace.c import y\n    return y\n"
        "\n\ndef g():\n    from fxspace._b import z\n    import fxspace.d._e\n"
        "    from fxspace.c import _w\n    return z\n"
    )
    assert private_imports_in_functions(pkg) == ["fxspace/a.py:10", "fxspace/a.py:11",
                                                 "fxspace/a.py:12"]
