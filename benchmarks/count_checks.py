"""Count the hand-written input checks and the declared port constraints in nodes/ (issue 25).

A hand-written check is a ``raise BadInput(...)`` / ``raise self.bad_input(...)`` statement; a
declared constraint is one constraint keyword of an ``In(...)`` port declaration (channels,
same_size_as, finite, ge, gt, le, lt, min_items).  Usage::

    python benchmarks/count_checks.py [ROOT]      # ROOT defaults to the repository's nodes/
"""
from __future__ import annotations

import ast
import sys
from collections import Counter
from pathlib import Path

KEYWORDS = {"channels", "same_size_as", "finite", "ge", "gt", "le", "lt", "min_items"}


def _name(func: ast.expr) -> str:
    return func.id if isinstance(func, ast.Name) else func.attr if isinstance(func, ast.Attribute) else ""


def count(path: Path) -> tuple[int, int]:
    """(hand-written checks, declared constraints) in one file."""
    checks = constraints = 0
    for n in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(n, ast.Raise) and isinstance(n.exc, ast.Call) and _name(n.exc.func) in ("BadInput", "bad_input"):
            checks += 1
        elif isinstance(n, ast.Call) and _name(n.func) == "In":
            constraints += sum(k.arg in KEYWORDS for k in n.keywords)
    return checks, constraints


def main(root: Path) -> None:
    checks: Counter = Counter()
    declared: Counter = Counter()
    for f in sorted(root.rglob("*.py")):
        pkg = f.relative_to(root).parts[0] if len(f.relative_to(root).parts) > 1 else "."
        c, d = count(f)
        checks[pkg] += c
        declared[pkg] += d
    print(f"{'package':<10} {'hand-written':>12} {'declared':>9}")
    for pkg in sorted(set(checks) | set(declared)):
        print(f"{pkg:<10} {checks[pkg]:>12} {declared[pkg]:>9}")
    print(f"{'total':<10} {sum(checks.values()):>12} {sum(declared.values()):>9}")


if __name__ == "__main__":
    main(Path(sys.argv[1]) if len(sys.argv) > 1 else Path(__file__).resolve().parents[1] / "nodes")
