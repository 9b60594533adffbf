"""optim stays a numerics library: no web, queue or database imports."""

from __future__ import annotations

import subprocess
import sys

FORBIDDEN = ("fastapi", "celery", "sqlalchemy", "redis", "starlette", "kombu", "psycopg")
MODULES = (
    "optim",
    "optim.spline",
    "optim.cmaes",
    "optim.executors",
    "optim.objective",
    "optim.run",
    "optim.result",
    "optim.pca",
    "optim.interpolate",
    "optim.superpose",
    "optim.errors",
    "optim.outcome",
    "optim.family",
    "optim.family.spec",
    "optim.family.plan",
    "optim.family.checks",
    "optim.family.report",
    "optim.family.machine",
    "optim.family_run",
    "optim.sweep",
    "optim.clips",
)


def test_optim_imports_no_service_stack():
    code = (
        "import sys\n"
        + "".join(f"import {m}\n" for m in MODULES)
        + f"bad = [m for m in sys.modules if m.split('.')[0] in {FORBIDDEN!r}]\n"
        + "print(','.join(bad))\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == ""


def test_error_hierarchy():
    from optim import errors

    for name in (
        "EvaluationError",
        "InterpolationError",
        "BasisError",
        "ResultFileError",
        "ParamsError",
        "CheckpointError",
    ):
        assert issubclass(getattr(errors, name), errors.OptimError)
