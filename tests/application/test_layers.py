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
MODULES = ("application", *sorted(f"application.{p.stem}"
                                  for p in (ROOT / "application").glob("*.py")
                                  if p.stem != "__init__"))


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


#: The modules of service/ that answer a 4xx themselves: the one error mapping and the parsing
#: of what arrives (the body's bytes and JSON, query parameters, the path); every other refusal
#: is an application error that service/errors.py maps (application/errors.py).
HTTP_REFUSERS = {"service/errors.py", "service/body.py", "service/deps.py"}


def test_the_service_imports_nothing_of_the_domain():
    """The API reaches sim/ and optim/ only through application/: no module of service/
    imports them, so no domain error type is translated in a router."""
    graph = _project_imports()
    found = sorted(f"{m} -> {d}" for m, deps in graph.items() if m.split(".")[0] == "service"
                   for d in deps if d.split(".")[0] in ("sim", "optim"))
    assert found == []


def _raises_http_4xx(path: Path) -> list[int]:
    lines = []
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Raise) and isinstance(node.exc, ast.Call) and node.exc.args:
            name = getattr(node.exc.func, "id", getattr(node.exc.func, "attr", ""))
            code = node.exc.args[0]
            if name in ("HttpError", "HTTPException") and isinstance(code, ast.Constant) \
                    and 400 <= code.value < 500:
                lines.append(node.lineno)
    return lines


def test_no_router_refuses_a_request_itself():
    paths = sorted((ROOT / "service").rglob("*.py"))
    found = [f"{p.relative_to(ROOT)}:{n}" for p in paths
             if str(p.relative_to(ROOT)) not in HTTP_REFUSERS for n in _raises_http_4xx(p)]
    assert found == []
    assert all(_raises_http_4xx(ROOT / p) for p in HTTP_REFUSERS - {"service/errors.py"})
