"""The layers: `application` (the service's use cases) imports no web or queue code and nothing
of `service/` or `worker/`; the API's routers and the workers import it, and every project
import of those packages is at module top (none inside a function to dodge an import cycle)."""

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
