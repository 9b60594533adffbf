"""Response bodies built from store records (one place per kind of record)."""

from __future__ import annotations

from typing import Any

from fastapi import Request

from application.answers import Answer
from service import schemas
from service.deps import url_for
from store import Repository


def job_cmrt_id(repo: Repository, job: Any) -> str | None:
    """Id of the library CMRT a finished job added, or None (store lookup by job id)."""
    if not job.terminal:
        return None
    rec = repo.job_cmrt(job.id)
    return None if rec is None else rec.id


def job_out(job: Any, request: Request, cmrt_id: str | None = None) -> dict[str, Any]:
    return {
        "id": job.id,
        "url": url_for(request, "get_job", job_id=job.id),
        "name": job.name,
        "family": job.family,
        "task": job.task,
        "status": job.status,
        "stop_rule": job.stop_rule,
        "error": job.error,
        "seed": job.seed,
        "basis_id": job.basis_id,
        "created_at": job.created_at,
        "started_at": job.started_at,
        "finished_at": job.finished_at,
        "best_objective": job.best_objective,
        "best_params": job.best_params,
        "evaluations": job.evaluations,
        "iterations": job.iterations,
        "cancel_requested": job.cancel_requested,
        "start": None if job.start is None else job.start.to_json(),
        "cmrt_id": cmrt_id,
        "links": {
            "generations": url_for(request, "job_generations", job_id=job.id),
            "evaluations": url_for(request, "job_evaluations", job_id=job.id),
            "cancel": url_for(request, "cancel_job", job_id=job.id),
            "dashboard": url_for(request, "dashboard_job", job_id=job.id),
            "best": url_for(request, "job_best", job_id=job.id),
        },
    }


def generation_out(g: Any) -> dict[str, Any]:
    return {
        "iteration": g.iteration,
        "best": g.best,
        "median": g.median,
        "worst": g.worst,
        "sigma": g.sigma,
        "best_so_far": g.best_so_far,
        "evaluations": g.evaluations,
        "wall_time": g.wall_time,
        "created_at": g.created_at,
    }


def cmrt_out(r: Any, request: Request, full: bool = False) -> dict[str, Any]:
    d = {
        "id": r.id,
        "url": url_for(request, "get_cmrt", cmrt_id=r.id),
        "family": r.family,
        "task_parameters": r.task_parameters,
        "character": r.character,
        "objective": r.objective,
        "objective_without": r.objective_without,
        "winner": r.winner,
        "fell": r.fell,
        "job_id": r.job_id,
        "created_at": r.created_at,
    }
    if full:
        d.update(
            clip={"preparation": r.preparation, "duration": r.duration, "decay": r.decay,
                  "length": r.preparation + r.duration + r.decay},
            params=r.params,
            knot_times=r.knots,
            values=r.values,
            curve=r.curve,
            fell_without=r.fell_without,
            source={"job_id": r.job_id, "spec": r.spec,
                    "job_url": None if r.job_id is None
                    else url_for(request, "get_job", job_id=r.job_id)},
        )
    return d


def basis_out(b: Any, request: Request) -> dict[str, Any]:
    return {"id": b.id, "url": url_for(request, "get_basis", basis_id=b.id), "family": b.family,
            "k": b.k, "mean": b.mean, "components": b.components,
            "variance_explained": b.variance_explained, "members": b.members, "box": b.box,
            "created_at": b.created_at}


def answer_out(a: Answer, request: Request, offer: bool = True
               ) -> schemas.LibraryAnswer:
    """A library answer as served: its fields, each neighbour's URL and, with `offer` where
    the answer is not a good one, how to ask for a refinement."""
    out = schemas.LibraryAnswer.model_validate(a, from_attributes=True)
    for n in out.neighbours:
        n.url = url_for(request, "get_cmrt", cmrt_id=n.id)
    if offer and a.verdict != "good" and not a.exact:  # a member optimised there: nothing to refine
        out.refine = {"method": "POST", "url": url_for(request, "refine_cmrt"),
                      "body": {"family": a.family, "parameters": {a.key: a.value}},
                      "command": f"cmrt library refine --family {a.family} "
                                 f"{a.key}={a.value:g} --wait"}
    return out
