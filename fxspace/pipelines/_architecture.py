"""The architecture page's facts, read off the code so the page cannot drift.

``docs/concepts/architecture.md`` is prose with generated blocks between
``<!-- begin generated: NAME -->`` and ``<!-- end generated: NAME -->`` markers:

- ``layers``: the import layers, drawn from the layers contract in ``pyproject.toml``
  (what ``lint-imports`` enforces), with each module's job from its docstring;
- ``contracts``: the name of every import-linter contract;
- ``layout``: the package tree, each entry with the first sentence of its docstring;
- ``limits``: the size limits the tests hold (``tests/test_layout.py``);
- ``pipeline``: the members of the `Pipeline` protocol, with their signatures.

`write_architecture` fills the blocks (``fxspace docs`` calls it); `stale_blocks` names
the blocks whose text differs from the code (``tests/test_architecture_page.py``).
"""

from __future__ import annotations

import ast
import inspect
import re
import tomllib
from html import escape
from pathlib import Path

from fxspace.errors import FxspaceError
from fxspace.pipelines._registry import Pipeline
from fxspace.runs import write_text_atomic

PACKAGE = Path(__file__).resolve().parents[1]
ROOT = PACKAGE.parent
PAGE = ROOT / "docs" / "concepts" / "architecture.md"
BLOCKS = ("layers", "contracts", "layout", "limits", "pipeline")
_BLOCK = re.compile(
    r"(<!-- begin generated: (?P<name>[a-z]+) -->\n)(?P<body>.*?)"
    r"(<!-- end generated: (?P=name) -->)",
    re.S,
)


class ArchitecturePageError(FxspaceError):
    """The architecture page or the files it is read from are not as expected."""


def _importlinter(root: Path) -> dict:
    p = root / "pyproject.toml"
    try:
        cfg = tomllib.loads(p.read_text(encoding="utf-8"))["tool"]["importlinter"]
    except (OSError, KeyError, tomllib.TOMLDecodeError) as e:
        raise ArchitecturePageError(
            f"cannot read [tool.importlinter] from {p} ({e}); run from a source checkout"
        ) from None
    return cfg


def _doc_sentence(path: Path) -> str:
    """The first sentence of a module's docstring (its first paragraph, one line)."""
    doc = ast.get_docstring(ast.parse(path.read_text(encoding="utf-8"))) or ""
    para = " ".join(doc.split("\n\n")[0].split())
    m = re.match(r"(.+?\.)(?=\s+[A-Z]|$)", para)
    return (m.group(1) if m else para).rstrip(":.").replace("``", "`") + "."


def _module_file(name: str, package: Path) -> Path:
    parts = name.split(".")[1:]
    base = package.joinpath(*parts)
    for p in (base / "__init__.py", base.with_suffix(".py")):
        if p.is_file():
            return p
    raise ArchitecturePageError(
        f"the layers contract names {name}, which has no module under {package}; "
        "fix the contract in pyproject.toml"
    )


def layers(root: Path = ROOT, package: Path = PACKAGE) -> list[list[str]]:
    """The layers contract's layers, top to bottom, each a list of peer module names."""
    for c in _importlinter(root).get("contracts", []):
        if c.get("type") == "layers":
            return [[m.strip() for m in layer.split("|")] for layer in c["layers"]]
    raise ArchitecturePageError(f"{root / 'pyproject.toml'} has no layers contract")


def _layers_svg(rows: list[list[str]]) -> str:
    h, gap, w = 34, 10, 710
    height = len(rows) * (h + gap)
    out = [
        f'<svg xmlns="http://www.w3.org/2000/svg" width="760" height="{height}" '
        f'viewBox="0 0 760 {height}" role="img" aria-label="fxspace import layers">',
        '<defs><marker id="arr" markerWidth="8" markerHeight="8" refX="4" refY="7" '
        'orient="auto"><path d="M0,0 L8,0 L4,8 z" fill="#555"/></marker></defs>',
    ]
    for i, row in enumerate(rows):
        y = 10 + i * (h + gap)
        label = escape(" | ".join(m.removeprefix("fxspace.") for m in row))
        out.append(f'<rect x="40" y="{y}" width="{w}" height="{h}" rx="6" '
                   'fill="#e8f5e9" stroke="#37474f"/>')
        out.append(f'<text x="52" y="{y + 22}" font-family="monospace" font-size="13" '
                   f'fill="#000">{label}</text>')
        if i + 1 < len(rows):
            out.append(f'<line x1="20" y1="{y + 17}" x2="20" y2="{y + h + gap + 17}" '
                       'stroke="#555" stroke-width="2" marker-end="url(#arr)"/>')
    out.append("</svg>")
    return "\n".join(out)


def _block_layers(root: Path, package: Path) -> str:
    rows = layers(root, package)
    table = ["| layer | module | its job (first sentence of its docstring) |",
             "| --- | --- | --- |"]
    for i, row in enumerate(rows, 1):
        for m in row:
            job = _doc_sentence(_module_file(m, package)).replace("|", "\\|")
            table.append(f"| {i} | `{m}` | {job} |")
    return ('<div class="fx-diagram">\n' + _layers_svg(rows) + "\n</div>\n\n"
            + "\n".join(table) + "\n")


def _block_contracts(root: Path, package: Path) -> str:
    cfg = _importlinter(root)
    lines = [f"- **{c['name'].strip()}** (`{c['type']}`)" for c in cfg.get("contracts", [])]
    typed = "included" if not cfg.get("exclude_type_checking_imports") else "skipped"
    lines.append(f"- Imports under `if TYPE_CHECKING:` are {typed} when the contracts "
                 "are checked.")
    return "\n".join(lines) + "\n"


def _block_layout(root: Path, package: Path) -> str:
    entries = []
    for p in sorted(package.iterdir()):
        if p.is_dir() and (p / "__init__.py").is_file():
            entries.append((p.name + "/", _doc_sentence(p / "__init__.py").replace("`", "")))
        elif p.suffix == ".py" and p.name != "__init__.py":
            entries.append((p.name, _doc_sentence(p).replace("`", "")))
    width = max(len(n) for n, _ in entries) + 2
    lines = [f"{package.name}/"] + [f"  {n:<{width}}{d}" for n, d in entries]
    return "```\n" + "\n".join(lines) + "\n```\n"


def _test_constant(path: Path, name: str) -> int:
    tree = ast.parse(path.read_text(encoding="utf-8"))
    for node in tree.body:
        if (isinstance(node, ast.Assign) and any(getattr(t, "id", None) == name
                                                 for t in node.targets)):
            return ast.literal_eval(node.value)
    raise ArchitecturePageError(f"{path} defines no {name}; the limits block reads it")


def _block_limits(root: Path, package: Path) -> str:
    t = root / "tests" / "test_layout.py"
    fn, mod = _test_constant(t, "MAX_LINES"), _test_constant(t, "MAX_MODULE_LINES")
    return (f"- No function in `fxspace/` is longer than **{fn} lines**, and no module "
            f"longer than **{mod} lines** (`tests/test_layout.py`).\n")


def _block_pipeline(root: Path, package: Path) -> str:
    doc = inspect.getdoc(Pipeline) or ""
    head, _, items = doc.partition("\n\n")
    sig = inspect.signature(Pipeline.run).replace(parameters=list(
        inspect.signature(Pipeline.run).parameters.values())[1:])
    return f"{head}\n\n{items}\n\n(`run{sig}`, from `fxspace.pipelines.Pipeline`.)\n"


_MAKERS = {"layers": _block_layers, "contracts": _block_contracts, "layout": _block_layout,
           "limits": _block_limits, "pipeline": _block_pipeline}


def generated_blocks(root: Path = ROOT, package: Path = PACKAGE) -> dict[str, str]:
    """Each generated block's text, read off the code under ``root``."""
    return {name: _MAKERS[name](root, package) for name in BLOCKS}


def _fill(text: str, blocks: dict[str, str], page: Path) -> str:
    seen = {m.group("name") for m in _BLOCK.finditer(text)}
    if missing := [b for b in BLOCKS if b not in seen]:
        raise ArchitecturePageError(
            f"{page} has no generated block {missing}; add "
            f"'<!-- begin generated: NAME -->' / '<!-- end generated: NAME -->' lines")
    return _BLOCK.sub(lambda m: m.group(1) + blocks[m.group("name")] + m.group(4), text)


def stale_blocks(page: Path = PAGE, root: Path = ROOT, package: Path = PACKAGE) -> list[str]:
    """Names of the page's generated blocks that differ from the code (empty: up to date)."""
    text = Path(page).read_text(encoding="utf-8")
    blocks = generated_blocks(root, package)
    have = {m.group("name"): m.group("body") for m in _BLOCK.finditer(text)}
    return [b for b in BLOCKS if have.get(b) != blocks[b]]


def write_architecture(page: Path = PAGE, root: Path = ROOT, package: Path = PACKAGE) -> Path:
    """Fill the generated blocks of the architecture page from the code; returns its path.

    **Arguments:**

    - `page`: the Markdown page with ``<!-- begin generated: NAME -->`` markers.
    - `root`: the source checkout (its ``pyproject.toml`` and ``tests/``).
    - `package`: the ``fxspace`` package folder.

    **Returns:** `page`, written atomically (unchanged text is not rewritten).
    """
    page = Path(page)
    text = page.read_text(encoding="utf-8")
    new = _fill(text, generated_blocks(root, package), page)
    if new != text:
        write_text_atomic(page, new)
    return page
