"""The layers: `application` (the service's use cases) imports no web or queue code and nothing
of `service/` or `worker/`; the API's routers and the workers import it, and every project
import of those packages is at module top (none inside a function to dodge an import cycle).
No project module imports another in a circle, and nothing but `cli/` imports `cli/`."""

from __future__ import annotations

import ast
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
PROJECT = ("application", "cli", "cmrt", "optim", "service", "sim", "store", "worker")
FORBIDDEN = ("fastapi", "starlette", "celery", "kombu", "redis", "service", "worker", "cli")
MODULES = ("application", "application.admission", "application.bases", "application.families",
           "application.jobs", "application.library")


def test_application_imports_no_web_queue_service_or_worker_code():
    code = ("import sys\n" + "".join(f"import {m}\n" for m in MODULES)
            + f"bad = [m for m in sys.modules if m.split('.')[0] in {FORBIDDEN!r}]\n"
            + "print(','.join(sorted(bad)))\n")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         check=True, cwd=ROOT)
    assert out.stdout.strip() == ""


def _imports_inside_functions(path: Path) -> list[str]:
    found = []
    for node in ast.walk(ast.parse(path.read_text())):
        if not isinstance(node, ast.FunctionDef | ast.AsyncFunctionDef):
            continue
        for inner in ast.walk(node):
            if isinstance(inner, ast.ImportFrom) and inner.module and \
                    inner.module.split(".")[0] in PROJECT:
                found.append(f"{path.relative_to(ROOT)}:{inner.lineno} {inner.module}")
            elif isinstance(inner, ast.Import):
                found += [f"{path.relative_to(ROOT)}:{inner.lineno} {a.name}" for a in inner.names
                          if a.name.split(".")[0] in PROJECT]
    return found


def test_use_cases_are_imported_at_module_top():
    paths = [*(ROOT / "application").glob("*.py"), *(ROOT / "service" / "routers").glob("*.py")]
    assert [f for p in sorted(paths) for f in _imports_inside_functions(p)] == []


def test_the_routers_and_workers_use_the_application_layer():
    """What serves only the API (admission, the library, bases, families) is not in worker/."""
    assert not (ROOT / "worker" / "library.py").exists()
    assert not (ROOT / "worker" / "admission.py").exists()
    for name in ("jobs", "families", "bases", "cmrts"):
        text = (ROOT / "service" / "routers" / f"{name}.py").read_text()
        assert "from application" in text and "from worker" not in text, name


def _project_imports() -> dict[str, set[str]]:
    """Each project module -> the project modules it imports (at module top or in a function)."""
    paths = {}
    for pkg in PROJECT:
        for p in (ROOT / pkg).rglob("*.py"):
            name = ".".join(p.relative_to(ROOT).with_suffix("").parts)
            paths[name.removesuffix(".__init__")] = p
    graph = {}
    for name, p in paths.items():
        deps = set()
        for node in ast.walk(ast.parse(p.read_text())):
            targets = []
            if isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
                targets = [node.module, *(f"{node.module}.{a.name}" for a in node.names)]
            elif isinstance(node, ast.Import):
                targets = [a.name for a in node.names]
            deps |= {t for t in targets if t in paths and t != name}
        graph[name] = deps
    return graph


def test_no_import_circle_between_project_modules():
    graph = _project_imports()
    circles = []
    for start in graph:  # a depth-first walk from each module back to itself
        stack, seen = [(start, (start,))], set()
        while stack:
            mod, path = stack.pop()
            for dep in graph[mod]:
                if dep == start:
                    circles.append(" -> ".join((*path, start)))
                elif dep not in seen:
                    seen.add(dep)
                    stack.append((dep, (*path, dep)))
    assert circles == []


def test_nothing_outside_the_command_line_imports_it():
    """`python -m service` / `python -m worker` run their package's command, not `cli/`."""
    graph = _project_imports()
    assert sorted(m for m, deps in graph.items() if not m.startswith("cli")
                  and any(d == "cli" or d.startswith("cli.") for d in deps)) == []
