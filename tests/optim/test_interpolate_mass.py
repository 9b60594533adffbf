"""CMRTs of the domino family interpolated along the block's mass: the library function and
`cmrt interpolate --param mass` (results built from real domino specs)."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import yaml

from optim.interpolate import interpolate
from optim.result import OptimizationResult
from sim.spec import parse_spec

EXAMPLE = Path(__file__).resolve().parents[2] / "examples" / "domino.yaml"
CMRT = Path(sys.executable).parent / "cmrt"


def _result(mass: float, params: np.ndarray) -> OptimizationResult:
    data = yaml.safe_load(EXAMPLE.read_text())
    data["name"] = f"domino_m{mass:g}"
    data["task"]["mass"] = mass
    return OptimizationResult.build(parse_spec(data), params, objective=1.0,
                                    baseline_objective=20.0)


@pytest.fixture
def members() -> list[OptimizationResult]:
    rng = np.random.default_rng(3)
    return [_result(m, rng.random(8)) for m in (60.0, 120.0)]


def test_mass_is_a_task_parameter(members):
    assert [r.task_parameters()["mass"] for r in members] == [60.0, 120.0]
    mid = interpolate(members, 90.0, key="mass")
    assert (mid.lower_value, mid.upper_value, mid.weight) == (60.0, 120.0, 0.5)
    spec = members[0].task_spec()
    a, b = (np.asarray(r.params) for r in members)
    np.testing.assert_allclose(mid.params(spec), 0.5 * (a + b), atol=1e-12)


def test_cli_interpolates_along_mass(members, tmp_path):
    paths = []
    for r in members:
        paths.append(tmp_path / f"{r.name}.json")
        r.save(paths[-1])
    out = subprocess.run([str(CMRT), "interpolate", *map(str, paths), "--at", "80",
                          "--param", "mass"], capture_output=True, text=True, check=True)
    data = json.loads(out.stdout)
    assert data["key"] == "mass" and data["value"] == 80.0
    assert data["weight"] == pytest.approx(1.0 / 3.0)
    bad = subprocess.run([str(CMRT), "interpolate", *map(str, paths), "--at", "80",
                          "--param", "mass_kg"], capture_output=True, text=True)
    assert bad.returncode == 2 and "mass_kg" in bad.stderr
