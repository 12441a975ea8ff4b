"""No module of fxspace imports a private module (or a private name) of another package
(issue 46): a JAX or NumPy release may move those without notice. The one exception,
`fxspace/_jax_private.py`, says why there is no public way and is tested by
``tests/test_jax_private.py``."""

import ast
from pathlib import Path

PACKAGE = Path(__file__).resolve().parent.parent / "fxspace"
ALLOWED = {"_jax_private.py"}


def _private(part: str) -> bool:
    return part.startswith("_") and not (part.startswith("__") and part.endswith("__"))


def _offences(tree: ast.AST) -> list[str]:
    """``import X._y`` / ``from X._y import ...`` / ``from X import _y`` with X not fxspace
    (every statement, function-level ones included; relative imports are fxspace's own)."""
    out = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            mods = [(a.name, []) for a in node.names]
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            mods = [(node.module, [a.name for a in node.names])]
        else:
            continue
        for mod, names in mods:
            parts = mod.split(".")
            if parts[0] == "fxspace":
                continue
            if any(_private(p) for p in parts[1:]) or any(_private(n) for n in names):
                out.append(f"line {node.lineno}: {mod} {names or ''}".strip())
    return out


def test_no_private_module_of_another_package_is_imported():
    bad = []
    for f in sorted(PACKAGE.rglob("*.py")):
        if f.name in ALLOWED and f.parent == PACKAGE:
            continue
        text = f.read_text()
        rel = f.relative_to(PACKAGE.parent)
        bad += [f"{rel} {o}" for o in _offences(ast.parse(text))]
        if "jax._src" in text:  # strings too (importlib.import_module("jax._src..."))
            bad.append(f"{rel}: mentions jax._src")
    assert not bad, (
        "private modules of other packages imported (use a public API, or move the use into "
        "fxspace/_jax_private.py with a reason and a test in tests/test_jax_private.py):\n"
        + "\n".join(bad)
    )


def test_the_check_can_fail():
    src = (
        "from jax._src import config\nimport jax._src.xla_bridge\nfrom numpy import _core\n"
        "def f():\n    from jax.experimental import _private_thing\n"
        "from fxspace.cluster._fcm import x\nfrom __future__ import annotations\n"
        "from jax.experimental import compilation_cache\n"
    )
    got = _offences(ast.parse(src))
    assert [g.split(":")[0] for g in got] == ["line 1", "line 2", "line 3", "line 5"]
