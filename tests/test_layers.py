"""The package's layers only look down: a module imports its own package or a lower layer, never a higher
one, and never a peer of its own layer (docs/architecture.md draws the picture)."""

import ast
from pathlib import Path

import tvf

LAYERS: list[tuple[str, ...]] = [
    ("__init__", "errors"),
    ("geometry", "io", "seeds"),
    ("device", "parallel", "runs", "weights", "fusion"),
    ("tasks", "views"),
    ("models", "sim", "envs"),
    ("data", "planning"),
    ("policies",),
    ("train", "evaluate", "api"),
    ("viz", "robot"),
    ("experiment",),
    ("cli",),
    ("__main__",),
]
RANK = {name: i for i, names in enumerate(LAYERS) for name in names}
ROOT = Path(tvf.__file__).parent


def unit(path: Path) -> str:
    """The top-level module or package a file belongs to (``models`` for ``models/gctn.py``)."""
    return path.relative_to(ROOT).parts[0].removesuffix(".py")


def tvf_imports(path: Path) -> list[tuple[int, str]]:
    """(line, top-level tvf unit) of every ``tvf`` import in a file, inside functions too."""
    out = []
    for node in ast.walk(ast.parse(path.read_text())):
        names = []
        if isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            names = [node.module]
        elif isinstance(node, ast.Import):
            names = [a.name for a in node.names]
        for name in names:
            parts = name.split(".")
            if parts[0] == "tvf":
                out.append((node.lineno, parts[1] if len(parts) > 1 else "__init__"))
    return out


def test_every_module_has_a_layer():
    units = {unit(p) for p in ROOT.rglob("*.py")}
    assert units <= set(RANK), f"add {sorted(units - set(RANK))} to LAYERS"


LAZY_EXPORTS = {("__init__", "api")}
"""The package root re-exports the Python API on first use (PEP 562 ``__getattr__``), never at import."""


def test_no_module_imports_a_higher_layer_or_a_peer():
    wrong = []
    for path in sorted(ROOT.rglob("*.py")):
        here = unit(path)
        for line, there in tvf_imports(path):
            if (here, there) in LAZY_EXPORTS:
                continue
            if there != here and RANK[there] >= RANK[here]:
                wrong.append(f"{path.relative_to(ROOT)}:{line} ({here}) imports tvf.{there}")
    assert not wrong, "imports that look up or sideways:\n" + "\n".join(wrong)


def test_the_checker_sees_an_upward_import(tmp_path):
    bad = tmp_path / "bad.py"
    bad.write_text("def f():\n    from tvf.cli import main\n")
    assert tvf_imports(bad) == [(2, "cli")]


def test_the_root_imports_the_api_only_on_first_use():
    import subprocess
    import sys

    code = "import sys, tvf; assert 'torch' not in sys.modules and 'tvf.api' not in sys.modules; tvf.Planner"
    subprocess.run([sys.executable, "-c", code], check=True)
