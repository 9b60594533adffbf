"""application.library: interpolation reads only the neighbours it needs and answers exactly what
`optim.interpolate.interpolate` answers over the whole family."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import yaml

from application.library import LibraryCmrt, interpolated_at
from optim.errors import InterpolationError
from optim.interpolate import interpolate
from optim.spline import decode, sample_curve
from sim.spec import parse_spec
from store import CmrtEntry, open_repository

ROOT = Path(__file__).resolve().parents[2]


def _entry(duration: float, objective: float, seed: int, spec_stored: bool = True) -> CmrtEntry:
    doc = yaml.safe_load((ROOT / "examples" / "fast_bend.yaml").read_text())
    doc["clip"]["duration"] = duration
    spec = parse_spec(doc)
    params = np.random.default_rng(seed).uniform(0.2, 0.8, spec.cmrt_dimension)
    spline = decode(spec, params)
    return CmrtEntry(
        family=spec.family_name, character=spec.character.model_dump(mode="json"),
        task_parameters=spec.task_parameters(), preparation=spec.clip.preparation,
        duration=duration, decay=spec.clip.decay, params=[float(v) for v in params],
        knots=[float(v) for v in spline.knot_times], values=[float(v) for v in spline.values],
        curve=sample_curve(spline), objective=objective,
        spec=spec.model_dump(mode="json") if spec_stored else None,
    )  # fmt: skip


@pytest.fixture
def repo(tmp_path):
    repo = open_repository(f"sqlite:///{tmp_path}/lib.db")
    # Duplicates at 0.3 (the lower objective wins) and at 0.5 (a tie: the newest wins, as
    # `interpolate` keeps the first of the store's newest-first order), one without a spec.
    for i, (d, obj) in enumerate([(0.2, 2.0), (0.3, 2.5), (0.3, 1.5), (0.4, 2.0), (0.5, 1.0),
                                  (0.5, 1.0), (0.6, 3.0)]):
        repo.add_cmrt(_entry(d, obj, seed=i))
    repo.add_cmrt(_entry(0.35, 0.5, seed=99, spec_stored=False))
    yield repo
    repo.engine.dispose()


def _whole_family(repo, family: str, value: float, extrapolate: bool):
    items, _ = repo.list_cmrts(family, limit=10_000)
    members = [LibraryCmrt.of(r) for r in items if r.spec is not None]
    return interpolate(members, value, key="duration", extrapolate=extrapolate).to_dict()


@pytest.mark.parametrize("value,extrapolate", [
    (0.2, False), (0.3, False), (0.5, False), (0.6, False), (0.25, False), (0.33, False),
    (0.45, False), (0.55, False), (0.1, True), (0.65, True)])
def test_neighbours_give_the_whole_family_answer(repo, value, extrapolate):
    family = repo.cmrt_families()[0][0]
    want = _whole_family(repo, family, value, extrapolate)
    interp, recs = interpolated_at(repo, family, "duration", value, extrapolate=extrapolate)
    got = interp.to_dict()
    assert [r.id for r in recs] == list(dict.fromkeys([want["lower"], want["upper"]]))
    for k in ("weight", "exact", "extrapolated", "length", "knot_times", "values"):
        assert got[k] == want[k], k


def test_outside_the_range_is_refused_without_extrapolate(repo):
    family = repo.cmrt_families()[0][0]
    with pytest.raises(InterpolationError, match="outside the sampled range"):
        interpolated_at(repo, family, "duration", 0.7)
    with pytest.raises(InterpolationError, match="no library CMRTs"):
        interpolated_at(repo, family, "force", 1.0)
