"""Plain, frozen records returned by the repository (never ORM objects) and job states.

Timestamps are timezone-aware UTC datetimes. JSON-valued fields hold plain lists and dicts;
treat them as read-only.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, fields
from datetime import datetime
from typing import Any

# ---- job states -------------------------------------------------------------------------
QUEUED = "queued"
RUNNING = "running"
CONVERGED = "converged"
STOPPED = "stopped"
FAILED = "failed"
CANCELLED = "cancelled"

JOB_STATUSES: tuple[str, ...] = (QUEUED, RUNNING, CONVERGED, STOPPED, FAILED, CANCELLED)
TERMINAL_STATUSES: frozenset[str] = frozenset({CONVERGED, STOPPED, FAILED, CANCELLED})

#: Legal status changes: queued -> running -> converged | stopped | failed | cancelled;
#: a queued job may also be cancelled or failed before it ever runs.
TRANSITIONS: Mapping[str, frozenset[str]] = {
    QUEUED: frozenset({RUNNING, FAILED, CANCELLED}),
    RUNNING: frozenset({CONVERGED, STOPPED, FAILED, CANCELLED}),
    CONVERGED: frozenset(),
    STOPPED: frozenset(),
    FAILED: frozenset(),
    CANCELLED: frozenset(),
}

# ---- evaluation states ------------------------------------------------------------------
PENDING = "pending"
DONE = "done"
EVAL_FAILED = "failed"


@dataclass(frozen=True)
class JobStart:
    """Where a job's search starts (None on a job: the flat spline): `origin` says what it
    came from (the JSON form's "from"), `x0` the full parameters, `sigma0` a smaller initial
    step (box units) than the spec's, `cmrts` the library CMRTs it was made of, `kind`
    "refine" for a refinement. Its JSON form (`to_json`, `from_json`) is what the store keeps
    and the API shows."""

    origin: str
    x0: tuple[float, ...]
    sigma0: float | None = None
    cmrts: tuple[str, ...] | None = None
    kind: str | None = None

    def to_json(self) -> dict[str, Any]:
        """The JSON form: "kind" (if any), "from", "x0", then "sigma0" and "cmrts" if set."""
        doc: dict[str, Any] = {} if self.kind is None else {"kind": self.kind}
        doc.update({"from": self.origin, "x0": [float(v) for v in self.x0]})
        if self.sigma0 is not None:
            doc["sigma0"] = float(self.sigma0)
        if self.cmrts is not None:
            doc["cmrts"] = list(self.cmrts)
        return doc

    @classmethod
    def from_json(cls, doc: Mapping[str, Any]) -> JobStart:
        """The record of a JSON form (`to_json`'s)."""
        cmrts = doc.get("cmrts")
        return cls(origin=doc["from"], x0=tuple(float(v) for v in doc["x0"]),
                   sigma0=None if doc.get("sigma0") is None else float(doc["sigma0"]),
                   cmrts=None if cmrts is None else tuple(cmrts), kind=doc.get("kind"))


@dataclass(frozen=True)
class JobRecord:
    id: str
    name: str
    family: str
    task: str
    spec: dict[str, Any]
    #: SHA-256 of the spec's canonical text (cmrt.canonical): the key processes cache it under.
    spec_hash: str
    seed: int | None
    workers: int
    status: str
    stop_rule: str | None
    error: str | None
    basis_id: str | None
    created_at: datetime
    started_at: datetime | None
    finished_at: datetime | None
    #: Lowest objective recorded over all generations (None before the first generation).
    best_objective: float | None
    #: Parameter vector of `best_objective`, if the driver passed it to `record_generation`.
    best_params: list[float] | None
    #: Cumulative evaluations after the latest recorded generation.
    evaluations: int
    #: Number of recorded generations (= latest iteration + 1).
    iterations: int
    cancel_requested: bool
    driver_owner: str | None
    lease_expires_at: datetime | None
    heartbeat_at: datetime | None
    #: Where the search started; None: the flat spline.
    start: JobStart | None = None

    @property
    def terminal(self) -> bool:
        return self.status in TERMINAL_STATUSES


@dataclass(frozen=True)
class GenerationRecord:
    job_id: str
    #: 0-based generation number.
    iteration: int
    best: float
    median: float
    worst: float
    sigma: float
    best_so_far: float
    #: Cumulative evaluations of the job after this generation.
    evaluations: int
    wall_time: float
    #: The asked parameter vectors of this generation, in index order.
    candidates: list[list[float]]
    #: Pickled optimizer after telling this generation; None when not requested.
    optimizer_state: bytes | None
    created_at: datetime


@dataclass(frozen=True)
class EvaluationRecord:
    job_id: str
    generation: int
    index: int
    params: list[float] | None
    status: str
    objective: float | None
    fell: bool | None
    attempts: int
    cpu_seconds: float | None
    error: str | None
    details: dict[str, Any] | None
    created_at: datetime
    updated_at: datetime
    fingerprint: str | None = None  # the evaluating process's numeric fingerprint


@dataclass(frozen=True)
class GenerationCounts:
    """How many evaluations of one generation are in each state."""

    pending: int = 0
    done: int = 0
    failed: int = 0

    @property
    def total(self) -> int:
        return self.pending + self.done + self.failed

    @property
    def resolved(self) -> int:
        """Evaluations that will not change any more (done or failed)."""
        return self.done + self.failed


@dataclass(frozen=True)
class EvaluationClaim:
    """What `claim_evaluation` found: what a worker needs to run one candidate (or skip it).

    `status` and `attempts` are the evaluation's after the claim: a `pending` status means this
    claim counted an attempt (`attempts` includes it); `done` / `failed` means nothing was
    counted and the work must be skipped. `job_status` is the job's status at the same moment.
    """

    job_id: str
    generation: int
    index: int
    status: str
    attempts: int
    params: list[float] | None
    job_status: str

    @property
    def job_terminal(self) -> bool:
        return self.job_status in TERMINAL_STATUSES


#: `CmrtEntry.winner`: the best searched candidate, or the flat spline (no anticipation).
WINNER_SEARCH = "search"
WINNER_FLAT = "flat"
WINNERS: tuple[str, ...] = (WINNER_SEARCH, WINNER_FLAT)


@dataclass(frozen=True, kw_only=True)
class CmrtEntry:
    """A library CMRT as a caller adds it (`add_cmrt`); `CmrtRecord` adds the stored id and
    time. The one list of a library entry's fields (the `cmrts` table has a column each)."""

    family: str
    #: {"model": ..., "height": ..., "mass": ...}
    character: dict[str, Any]
    #: Library keys of the task, e.g. {"duration": 0.4, "force": 250.0}.
    task_parameters: dict[str, float]
    preparation: float
    duration: float
    decay: float
    #: The parameter vector in [0, 1]^d.
    params: list[float]
    #: Decoded spline knot times (s) and control values (m).
    knots: list[float]
    values: list[Any]
    #: Sampled curve, as produced by optim (e.g. {"t": [...], "x": [...]}).
    curve: Any
    objective: float
    #: Objective of the flat spline (no anticipation) on the same task.
    objective_without: float | None = None
    fell: bool = False
    fell_without: bool | None = None
    #: Which candidate this entry is: WINNER_SEARCH (the best CMA-ES found) or WINNER_FLAT
    #: (the flat spline did better, so the entry is the flat spline: never worse than it).
    winner: str = WINNER_SEARCH
    job_id: str | None = None
    spec: dict[str, Any] | None = None


@dataclass(frozen=True, kw_only=True)
class CmrtRecord(CmrtEntry):
    id: str
    created_at: datetime


# ---- family states ------------------------------------------------------------------------
FAMILY_RUNNING = "running"
FAMILY_DONE = "done"
FAMILY_STATUSES: tuple[str, ...] = (FAMILY_RUNNING, FAMILY_DONE, FAILED, CANCELLED)
FAMILY_TERMINAL: frozenset[str] = frozenset({FAMILY_DONE, FAILED, CANCELLED})


@dataclass(frozen=True)
class FamilyRecord:
    id: str
    family: str
    param: str
    #: The family request (optim.family.spec.FamilySpec JSON form).
    spec: dict[str, Any]
    #: SHA-256 of the request's canonical text (cmrt.canonical).
    spec_hash: str
    status: str
    error: str | None
    cancel_requested: bool
    created_at: datetime
    finished_at: datetime | None
    #: run id -> job id of every run started so far.
    runs: dict[str, str]

    @property
    def terminal(self) -> bool:
        return self.status in FAMILY_TERMINAL


@dataclass(frozen=True)
class FamilyScan:
    """What a family driver reads of a family at one step, in one store call
    (`FamilyRepository.family_scan`): the family, the job of every run started so far (run
    id -> job), the result documents of the finished runs asked for (run id -> document),
    the probes' outcomes (JSON data; None before they are evaluated)."""

    family: FamilyRecord
    jobs: dict[str, JobRecord]
    results: dict[str, Any]
    probes: Any | None


@dataclass(frozen=True, slots=True)  # no __dict__: a library keeps thousands (store.library)
class CmrtKey:
    """What picking and listing library CMRTs by task parameter needs, without their curves,
    splines and specs: `LibraryRepository.cmrt_keys` and `find_cmrt_keys` (a CMRT's summary
    fields, as a `CmrtRecord` names them)."""

    id: str
    task_parameters: dict[str, float]
    objective: float
    #: Number of spline knots, and whether the CMRT has vertical control values.
    knots: int
    vertical: bool
    #: Whether the entry stores the spec it was optimised for (interpolation needs it).
    has_spec: bool
    created_at: datetime
    #: The clip around the task window (s) and the character, which interpolation keeps equal.
    preparation: float = 0.0
    decay: float = 0.0
    character: dict[str, Any] | None = None
    family: str = ""
    objective_without: float | None = None
    winner: str = "search"
    fell: bool = False
    job_id: str | None = None


@dataclass(frozen=True)
class BasisRecord:
    id: str
    family: str
    k: int
    mean: list[float]
    #: k rows of length d.
    components: list[list[float]]
    variance_explained: list[float]
    #: Ids of the library CMRTs the basis was fitted on.
    members: list[str]
    #: Bounds of the reduced coordinates, e.g. {"low": [...], "high": [...]}.
    box: Any
    created_at: datetime


@dataclass(frozen=True)
class VerificationRecord:
    """The stored outcome of simulating a CMRT the library served (`add_verification`)."""

    id: str
    family: str
    spec_hash: str
    params_hash: str
    #: "member", "interpolated" or "refined".
    source: str
    #: Ids of the library CMRTs it was built from.
    members: list[str]
    #: objective, fell, fall_direction, task_success, status, error, cpu_seconds.
    outcome: dict[str, Any]
    created_at: datetime


@dataclass(frozen=True)
class CharacterRecord:
    """A named character definition kept for reuse by name (`add_character`): the definition
    as it was given (JSON data, validated by the caller), the hash of its canonical text."""

    id: str
    name: str
    definition: dict[str, Any]
    definition_hash: str
    created_at: datetime


#: Field names of a library entry, in order (`CmrtEntry`).
CMRT_ENTRY_FIELDS: tuple[str, ...] = tuple(f.name for f in fields(CmrtEntry))
