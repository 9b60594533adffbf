"""Shared fixtures for the optim tests: small specs built in code (no files)."""

from __future__ import annotations

from typing import Any

import pytest

from sim.spec import TaskSpec, parse_spec


def make_spec(
    name: str = "t",
    *,
    duration: float = 0.4,
    family: str | None = "bend",
    knots: int = 4,
    vertical: bool = False,
    **optimize: Any,
) -> TaskSpec:
    """A quiet-stance spec (cheap to build) with the given clip and CMRT/optimize settings."""
    return parse_spec(
        {
            "name": name,
            "family": family,
            "task": {"type": "quiet_stance"},
            "clip": {"preparation": 1.0, "duration": duration, "decay": 1.0},
            "cmrt": {"knots": knots, "vertical": vertical},
            "optimize": optimize,
        }
    )


@pytest.fixture
def spec() -> TaskSpec:
    return make_spec()


@pytest.fixture(name="make_spec")
def make_spec_fixture() -> Any:
    """The `make_spec` factory (test modules cannot import conftest reliably)."""
    return make_spec
