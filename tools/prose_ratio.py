"""Lines of prose (docstrings and comments) against lines of code, per module and in total.

A line is prose if it lies in a docstring (module, class or function) or
holds only a comment; code otherwise; blank lines count as neither. A code
line with a trailing comment counts as code.

Usage: python tools/prose_ratio.py [PACKAGE ...] [--top N]   (default: vpr)
"""
from __future__ import annotations

import argparse
import ast
import io
import tokenize
from pathlib import Path


def count(path: Path) -> tuple[int, int]:
    """(prose lines, code lines) of one Python file."""
    text = path.read_text(encoding="utf-8")
    prose: set[int] = set()
    for node in ast.walk(ast.parse(text)):
        if isinstance(node, (ast.Module, ast.ClassDef, ast.FunctionDef, ast.AsyncFunctionDef)) and node.body:
            first = node.body[0]
            if isinstance(first, ast.Expr) and isinstance(first.value, ast.Constant) \
                    and isinstance(first.value.value, str):
                prose.update(range(first.lineno, first.end_lineno + 1))
    code: set[int] = set()
    for tok in tokenize.generate_tokens(io.StringIO(text).readline):
        if tok.type == tokenize.COMMENT and tok.start[0] not in code:
            prose.add(tok.start[0])
        elif tok.type not in (tokenize.NL, tokenize.NEWLINE, tokenize.INDENT, tokenize.DEDENT, tokenize.COMMENT,
                              tokenize.ENDMARKER):
            lines = range(tok.start[0], tok.end[0] + 1)
            code.update(n for n in lines if n not in prose)
    prose -= code
    return len(prose), len(code)


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("packages", nargs="*", default=["vpr"])
    ap.add_argument("--top", type=int, default=15, help="modules listed, most prose per code line first")
    args = ap.parse_args(argv)
    rows = [(p, *count(p)) for pkg in args.packages for p in sorted(Path(pkg).rglob("*.py"))]
    prose, code = sum(r[1] for r in rows), sum(r[2] for r in rows)
    print(f"{' '.join(args.packages)}: {prose} lines of prose, {code} of code: 1 per {code / max(prose, 1):.2f}")
    for p, n_prose, n_code in sorted(rows, key=lambda r: -r[1] / max(r[2], 1))[:args.top]:
        print(f"  {p}: {n_prose} / {n_code} (1 per {n_code / max(n_prose, 1):.2f})")


if __name__ == "__main__":
    main()
