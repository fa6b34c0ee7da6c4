"""The house rules that no linter checks: no module imports another module's private name."""
import ast
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("vpr", "encoders", "pipelines", "research", "tests", "tools")


def private_imports(root: Path = ROOT) -> list[str]:
    """``from X import _name`` anywhere: a module's ``_name`` is its own (import-linter checks modules, not names)."""
    found = []
    for pkg in PACKAGES:
        for f in sorted((root / pkg).rglob("*.py")):
            for node in ast.walk(ast.parse(f.read_text(encoding="utf-8"))):
                if isinstance(node, ast.ImportFrom):
                    found += [f"{f.relative_to(root)}:{node.lineno}: {a.name}" for a in node.names
                              if a.name.startswith("_") and not a.name.startswith("__")]
    return found


def test_no_module_imports_another_modules_private_name():
    assert private_imports() == []


def test_the_check_finds_a_private_import(tmp_path):
    (tmp_path / "vpr").mkdir()
    (tmp_path / "vpr" / "a.py").write_text("from vpr.b import _hidden, public\n")
    assert private_imports(tmp_path) == ["vpr/a.py:1: _hidden"]
