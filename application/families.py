"""Families: submitting one (the request validated, the whole family admitted against the
job ceiling, then stored with its request's hash) and the typed request of a stored family,
kept by that hash in the process's one spec cache (`optim.objective.SPECS`): a page polling a
family and the family driver parse it once per process, not at every poll or scan."""

from __future__ import annotations

from typing import Any

from application import admission
from cmrt.canonical import document_hash
from cmrt.settings import Settings
from optim.family import FamilySpec, parse_family, plan_runs
from optim.objective import SPECS
from store import FamilyRecord, Repository


def submit_family(repo: Repository, settings: Settings, data: Any
                  ) -> tuple[FamilyRecord, admission.Budget, int]:
    """Validate a family request (`optim.family.FamilyError`), admit it
    (`admission.BudgetExceeded`) and store it; returns the family, its budget and the number
    of runs of its plan."""
    fs = parse_family(data)
    budget = admission.family_budget(fs, settings)
    doc = fs.to_dict()
    spec_hash = document_hash(doc)
    SPECS.typed(spec_hash, lambda: fs)  # the family drivers of this process find it parsed
    fam = repo.create_family(doc, family=fs.family, param=fs.param, spec_hash=spec_hash)
    return fam, budget, len(plan_runs(fs))


def family_spec(fam: FamilyRecord) -> FamilySpec:
    """The typed request of a stored family (parsed only if this process has not got it;
    FamilyError if it does not parse)."""
    return SPECS.typed(fam.spec_hash, lambda: parse_family(fam.spec))


__all__ = ["family_spec", "submit_family"]
