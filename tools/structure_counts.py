"""Counts behind issue 29's "What a new engineer meets today", per package (docs/architecture.md "Issue 29, item by
item"): classes with more than two bases, `getattr`/`hasattr` calls (and of them the probes of a member by
literal name with a default, tools/check_structure.py rule 14), `setattr` calls on an object other than
self/cls, module-level import cycles, and the functions longer than --lines (compiled numba kernels marked).

Usage: python tools/structure_counts.py [--lines N] [CHECKOUT]
"""

from __future__ import annotations

import argparse
import ast
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

from check_structure import _dotted, _import_cycles, _import_edges, _module_name  # noqa: E402

PACKAGES = ("core", "drivers", "simulation", "calibration", "estimator", "daemon", "cli")


def _calls(tree: ast.AST, names: set[str]) -> list[ast.Call]:
    return [n for n in ast.walk(tree) if isinstance(n, ast.Call) and isinstance(n.func, ast.Name)
            and n.func.id in names and n.args]


def counts(root: Path, min_lines: int) -> tuple[list[tuple], list[tuple], list[str]]:
    """(per-package rows, long functions, import-cycle lines)."""
    rows, long_functions, paths, edges = [], [], {}, {}
    trees = {}
    for package in PACKAGES:
        for path in sorted((root / package).rglob("*.py")):
            trees[path] = (package, ast.parse(path.read_text(encoding="utf-8")))
            paths[_module_name(root, path)] = path
    for package in PACKAGES:
        bases = probes = literal_probes = setattrs = 0
        for path, (pkg, tree) in trees.items():
            if pkg != package:
                continue
            name = _module_name(root, path)
            edges[name] = _import_edges(tree, name, path, paths)
            bases += sum(1 for n in ast.walk(tree) if isinstance(n, ast.ClassDef) and len(n.bases) > 2)
            for call in _calls(tree, {"getattr", "hasattr"}):
                probes += 1
                attr = call.args[1].value if len(call.args) > 1 and isinstance(call.args[1], ast.Constant) else None
                if isinstance(attr, str) and (call.func.id == "hasattr" or len(call.args) > 2):
                    literal_probes += 1
            setattrs += sum(1 for c in _calls(tree, {"setattr"}) if _dotted(c.args[0]) not in ("self", "cls"))
            for n in ast.walk(tree):
                if isinstance(n, (ast.FunctionDef, ast.AsyncFunctionDef)):
                    lines = n.end_lineno - n.lineno + 1
                    if lines > min_lines:
                        kernel = any("njit" in ast.unparse(d) for d in n.decorator_list)
                        long_functions.append((lines, f"{path.relative_to(root)}:{n.lineno}", n.name, kernel))
        rows.append((package, bases, probes, literal_probes, setattrs))
    return rows, sorted(long_functions, reverse=True), _import_cycles(root, paths, edges)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("root", nargs="?", default=str(Path(__file__).resolve().parent.parent))
    ap.add_argument("--lines", type=int, default=80, help="list the functions longer than this (default 80)")
    args = ap.parse_args(argv)
    rows, long_functions, cycles = counts(Path(args.root), args.lines)
    print(f"{'package':12s} {'>2 bases':>8s} {'getattr/hasattr':>15s} {'by literal name':>15s} {'setattr':>7s}")
    for package, bases, probes, literal, setattrs in rows:
        print(f"{package:12s} {bases:8d} {probes:15d} {literal:15d} {setattrs:7d}")
    print(f"module-level import cycles: {len(cycles)}")
    for line in cycles:
        print("  " + line)
    print(f"functions longer than {args.lines} lines: {len(long_functions)}")
    for lines, where, name, kernel in long_functions:
        print(f"  {lines:4d} {where} {name}{' (numba kernel)' if kernel else ''}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
