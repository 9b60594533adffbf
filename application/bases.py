"""PCA bases: built from the library's CMRTs of a family, kept in the store, read back for a
job that searches in one (`optim.pca.Basis`)."""

from __future__ import annotations

from typing import Any

import numpy as np

from application.errors import InvalidRequest
from application.library import library_members
from optim.cmaes import MIN_DIMENSION
from optim.errors import BasisError
from optim.pca import DEFAULT_K, Basis, build_basis
from sim.spec import TaskSpec
from store import NotFound, Repository


class UnusableBasisError(InvalidRequest):
    """A job cannot search in the basis it names; the message names the field (`basis`)."""


def basis_from_record(rec: Any) -> Basis:
    """optim Basis from a store BasisRecord (box holds score_lo/score_hi, margin, cmrt)."""
    box = rec.box or {}
    return Basis(
        family=rec.family,
        k=rec.k,
        mean=np.asarray(rec.mean, dtype=float),
        components=np.asarray(rec.components, dtype=float),
        variance_explained=np.asarray(rec.variance_explained, dtype=float),
        members=list(rec.members),
        score_lo=np.asarray(box["score_lo"], dtype=float),
        score_hi=np.asarray(box["score_hi"], dtype=float),
        cmrt=dict(box.get("cmrt") or {}),
        margin=float(box.get("margin", 0.25)),
    )


def job_basis(repo: Repository, basis_id: str, spec: TaskSpec) -> Basis:
    """The stored basis a new job of `spec` will search in, once it is known to fit the spec
    (UnusableBasisError otherwise: unknown, built for other CMRT settings, or too few
    components)."""
    try:
        b = basis_from_record(repo.get_basis(basis_id))
    except NotFound:
        raise UnusableBasisError(f"basis: {basis_id!r} does not exist") from None
    try:
        b.check_spec(spec)
    except BasisError as err:
        raise UnusableBasisError(f"basis: {err}") from None
    if b.k < MIN_DIMENSION:
        raise UnusableBasisError(
            f"basis: {basis_id!r} has k = {b.k} component; a search needs at least "
            f"{MIN_DIMENSION} (pycma's update fails on one coordinate)")
    return b


def store_basis(repo: Repository, basis: Basis, family: str, members: list[str]) -> str:
    """Keep a PCA basis in the store (`basis_from_record` reads it back); returns its id."""
    return repo.add_basis(
        family=family,
        k=basis.k,
        mean=[float(v) for v in basis.mean],
        components=[[float(v) for v in row] for row in basis.components],
        variance_explained=[float(v) for v in basis.variance_explained],
        members=members,
        box={
            "score_lo": [float(v) for v in basis.score_lo],
            "score_hi": [float(v) for v in basis.score_hi],
            "margin": basis.margin,
            "cmrt": basis.cmrt,
            "content_id": basis.id,
        },
    )


def build_library_basis(repo: Repository, family: str, k: int = DEFAULT_K) -> str:
    """PCA basis of every library CMRT of `family`; stored, returns its id (BasisError when
    the family has no CMRTs or too few to reduce)."""
    members = library_members(repo, family)
    if not members:
        raise BasisError(f"no library CMRTs of family {family!r}")
    basis = build_basis(members, k=k, family=family)
    return store_basis(repo, basis, family, [m.name for m in members])


__all__ = ["UnusableBasisError", "basis_from_record", "build_library_basis", "job_basis",
           "store_basis"]
