"""The code's shape a newcomer relies on: one class per name across the product's packages (a
name found by search is the one concept it names)."""

from __future__ import annotations

import ast
from collections import defaultdict
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
#: The product's packages and the benchmarks (tests/ may repeat names: fakes stand in for them).
PACKAGES = ("sim", "optim", "store", "application", "worker", "service", "cli", "cmrt", "bench")


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
