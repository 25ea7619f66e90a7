"""No function or method in graphkit/ (nested ones included) is over MAX_LINES lines or over
MAX_CC cyclomatic complexity (radon's measure).  `make complexity` prints the whole table."""
from __future__ import annotations

from pathlib import Path

from radon.complexity import cc_visit

ROOT = Path(__file__).resolve().parents[1]
MAX_LINES = 60
MAX_CC = 15


def _blocks(blocks, prefix=""):
    """(qualified name, block) for every function, method and nested function."""
    for b in blocks:
        if hasattr(b, "methods"):  # a class (its methods are visited as functions too)
            continue
        name = f"{prefix}{b.fullname}" if not prefix else f"{prefix}{b.name}"
        yield name, b
        yield from _blocks(b.closures, f"{name}.")


def measure(root: Path = ROOT) -> list[tuple[str, str, int, int]]:
    """(file, qualified name, cyclomatic complexity, lines) of every function in graphkit/."""
    rows = []
    for f in sorted((root / "graphkit").rglob("*.py")):
        rel = f.relative_to(root).as_posix()
        for name, b in _blocks(cc_visit(f.read_text(encoding="utf-8"))):
            rows.append((rel, name, b.complexity, b.endline - b.lineno + 1))
    return rows


def over(cc: int, lines: int) -> bool:
    return cc > MAX_CC or lines > MAX_LINES


def table(rows) -> str:
    lines = [f"{'cc':>4} {'lines':>5}  function"]
    for rel, name, cc, n in sorted(rows, key=lambda r: (-r[2], -r[3], r[0], r[1])):
        flag = "  <- over" if over(cc, n) else ""
        lines.append(f"{cc:>4} {n:>5}  {rel}:{name}{flag}")
    return "\n".join(lines)


def test_no_function_in_graphkit_is_too_long_or_too_complex():
    rows = measure()
    assert any(name == "Studio.__init__" for _, name, _, _ in rows)  # methods are measured
    bad = [r for r in rows if over(r[2], r[3])]
    assert not bad, (f"over {MAX_LINES} lines or cyclomatic complexity {MAX_CC} "
                     f"(split them):\n{table(bad)}")


def test_nested_functions_are_measured(tmp_path):
    """A closure over the limits fails on its own (its outer function stays small)."""
    body = "".join(f"        if x == {i}:\n            return {i}\n" for i in range(MAX_CC + 1))
    (tmp_path / "graphkit").mkdir()
    (tmp_path / "graphkit" / "m.py").write_text(f"def outer():\n    def inner(x):\n{body}    return inner\n")
    got = {name: (cc, n) for _, name, cc, n in measure(tmp_path)}
    assert got["outer.inner"][0] == MAX_CC + 2 and over(*got["outer.inner"])
    assert not over(*got["outer"])


if __name__ == "__main__":  # make complexity
    rows = measure()
    print(table(rows))
    n = sum(over(r[2], r[3]) for r in rows)
    print(f"\n{len(rows)} functions; {n} over {MAX_LINES} lines or cyclomatic complexity {MAX_CC}")
