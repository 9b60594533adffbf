"""PCA bases: built from the library's CMRTs of a family, kept in the store, read back for a
job that searches in one (`optim.pca.Basis`)."""

from __future__ import annotations

from typing import Any

from application.errors import InvalidRequest, Missing
from application.library import library_members
from optim.cmaes import MIN_DIMENSION
from optim.errors import BasisError
from optim.pca import DEFAULT_K, Basis, build_basis
from sim.spec import TaskSpec
from store import NotFound, Repository


class UnusableBasisError(InvalidRequest):
    """A job cannot search in the basis it names; the message names the field (`basis`)."""


def basis_from_record(rec: Any) -> Basis:
    """optim Basis from a store BasisRecord (box holds score_lo/score_hi, margin, cmrt): the
    basis's own form (`Basis.from_dict`), its arrays in the record's columns."""
    box = {k: v for k, v in (rec.box or {}).items() if k != "content_id"}
    return Basis.from_dict({"family": rec.family, "k": rec.k, "mean": rec.mean,
                            "components": rec.components, "members": rec.members,
                            "variance_explained": rec.variance_explained, **box},
                           f"basis {rec.id}")


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
    d = basis.to_dict()
    return repo.add_basis(
        family=family, k=basis.k, mean=d["mean"], components=d["components"],
        variance_explained=d["variance_explained"], members=members,
        box={"score_lo": d["score_lo"], "score_hi": d["score_hi"], "margin": basis.margin,
             "cmrt": basis.cmrt, "content_id": basis.id})


def build_library_basis(repo: Repository, family: str, k: int = DEFAULT_K) -> str:
    """PCA basis of every library CMRT of `family`; stored, returns its id (Missing when the
    family has no library CMRTs, InvalidRequest when too few to reduce)."""
    members = library_members(repo, family)
    if not members:
        raise Missing(f"family: no library CMRTs of family {family!r}")
    try:
        basis = build_basis(members, k=k, family=family)
    except BasisError as err:
        raise InvalidRequest(str(err)) from None
    return store_basis(repo, basis, family, [m.name for m in members])


__all__ = ["UnusableBasisError", "basis_from_record", "build_library_basis", "job_basis",
           "store_basis"]
