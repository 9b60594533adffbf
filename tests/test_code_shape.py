"""The code's shape a newcomer relies on: one class per name across the product's packages (a
name found by search is the one concept it names), functions short enough to read whole, and a
base package (`cmrt/`) every layer may import."""

from __future__ import annotations

import ast
from collections import defaultdict
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
#: The product's packages and the benchmarks (tests/ may repeat names: fakes stand in for them).
PACKAGES = ("sim", "optim", "store", "application", "worker", "service", "cli", "cmrt", "bench")
#: Most lines of one function (its `def` to its last line) in the product (not tests/, bench/).
FUNCTION_LINES = 80


def _classes() -> dict[str, list[str]]:
    """Class name -> "path:line" of every class defined under PACKAGES."""
    found: dict[str, list[str]] = defaultdict(list)
    for package in PACKAGES:
        for path in sorted((ROOT / package).rglob("*.py")):
            for node in ast.walk(ast.parse(path.read_text(), str(path))):
                if isinstance(node, ast.ClassDef):
                    found[node.name].append(f"{path.relative_to(ROOT)}:{node.lineno}")
    return found


def test_one_class_per_name():
    found = _classes()
    assert len(found) > 100 and "SlotPool" in found  # the scan saw the packages
    repeated = {name: where for name, where in found.items() if len(where) > 1}
    assert repeated == {}, f"one class per name; these repeat: {repeated}"


def test_the_base_package_imports_nothing_else_of_the_product():
    """`cmrt/` (settings, canonical form, client, command-line pieces) is what every layer may
    import, so it imports no other package of the product, not even inside a function."""
    found = []
    for path in sorted((ROOT / "cmrt").glob("*.py")):
        for node in ast.walk(ast.parse(path.read_text(), str(path))):
            names = [a.name for a in node.names] if isinstance(node, ast.Import) else \
                [node.module or ""] if isinstance(node, ast.ImportFrom) and not node.level else []
            found += [f"{path.name}:{node.lineno} {n}" for n in names
                      if n.split(".")[0] in set(PACKAGES) - {"cmrt"}]
    assert found == []


def test_no_function_is_over_80_lines():
    sizes = {}
    for package in PACKAGES[:-1]:  # not bench/
        for path in sorted((ROOT / package).rglob("*.py")):
            for node in ast.walk(ast.parse(path.read_text(), str(path))):
                if isinstance(node, ast.FunctionDef | ast.AsyncFunctionDef):
                    where = f"{path.relative_to(ROOT)}:{node.name}"
                    sizes[where] = max(sizes.get(where, 0), node.end_lineno - node.lineno + 1)
    assert len(sizes) > 1000 and sizes["cli/main.py:build_parser"] > 5  # the scan measured
    long = {where: n for where, n in sizes.items() if n > FUNCTION_LINES}
    assert long == {}, f"functions over {FUNCTION_LINES} lines: split them into named parts"


def test_test_modules_have_unique_names():
    """pytest imports a test module outside a package by its basename: two folders holding the
    same name stop the whole run at collection ("import file mismatch")."""
    seen: dict[str, list[str]] = {}
    for path in sorted((ROOT / "tests").rglob("test_*.py")):
        if not (path.parent / "__init__.py").exists():
            seen.setdefault(path.name, []).append(str(path.relative_to(ROOT)))
    assert len(seen) > 50  # the scan saw the suite
    assert {n: w for n, w in seen.items() if len(w) > 1} == {}


def test_one_cache_implementation():
    """Every process-local cache is a `cmrt.lru.LRU`: the product writes least-recently-used
    bookkeeping (and its lock) once."""
    found = sorted(str(path.relative_to(ROOT)) for package in PACKAGES[:-1]
                   for path in (ROOT / package).rglob("*.py") if "move_to_end" in path.read_text())
    assert found == ["cmrt/lru.py"]


def test_benchmarks_import_the_product_as_installed():
    """bench/ is an installed package beside the product: no script edits `sys.path` to find
    it (a script would then run code other than what the interpreter has installed)."""
    found = sorted(str(path.relative_to(ROOT)) for path in (ROOT / "bench").rglob("*.py")
                   if "sys.path" in path.read_text())
    assert found == []
