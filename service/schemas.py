"""Response and request models of the HTTP API (for validation and the OpenAPI document).
The task spec itself is `sim.spec.TaskSpec`, the one model shared with the CLI."""

from __future__ import annotations

from datetime import datetime
from typing import Annotated, Any, Literal

from pydantic import BaseModel, ConfigDict, Field, WithJsonSchema, field_validator

from application.characters import definition_schema
from application.families import FamilyProgress, FamilyRunOut, FamilySpec
from application.jobs import TaskSpec
from application.simulations import (
    MAX_CMRT_PARAMS,
    CmrtChoice,
    InlineCmrt,
    JobBestCmrt,
    LibraryCmrtRef,
    ReplayRequest,
    SimulationRequest,
)
from cmrt.defaults import DEFAULT_SEED
from service.links import SIGNABLE

__all__ = ["MAX_CMRT_PARAMS", "CmrtChoice", "FamilyProgress", "FamilyRunOut", "FamilySpec",
           "InlineCmrt", "JobBestCmrt", "LibraryCmrtRef", "ReplayRequest", "SimulationRequest",
           "TaskSpec"]


#: The example body of `POST /jobs` in the OpenAPI document (examples/fast_bend.yaml's task;
#: tests/service checks that it is accepted).
JOB_EXAMPLE: dict[str, Any] = {
    "name": "fast_bend",
    "family": "bend",
    "clip": {"preparation": 1.0, "duration": 0.4, "decay": 1.2},
    "task": {"type": "pose_change",
             "target": {"waist": -90, "shoulder_r": 90, "shoulder_l": 90}},
    "optimize": {"threshold": 1.1, "max_evaluations": 700},
}
#: The example body of `POST /families`: the bend along its duration, by continuation from both
#: ends, with 0.3 s left out for the checks.
FAMILY_EXAMPLE: dict[str, Any] = {
    "spec": {**JOB_EXAMPLE, "optimize": {"max_evaluations": 120, "min_evaluations": 40,
                                         "window": 5, "improvement": 0.02}},
    "param": "clip.duration",
    "values": [0.2, 0.25, 0.3, 0.35, 0.4, 0.45],
    "strategy": "continuation",
    "from": "both",
    "leave_out": [0.3],
    "k": 2,
    "seed": 1,
}
#: The example body of `POST /bases`.
BASIS_EXAMPLE: dict[str, Any] = {"family": "bend", "k": 2}
#: POST /characters: a name and a definition (here the smallest that stands: docs/characters.md
#: has the full schema and examples/my_character.yaml a humanoid).
CHARACTER_EXAMPLE: dict[str, Any] = {
    "name": "my_character",
    "definition": {"reference": {"height": 1.75, "mass": 70.0}, "root": "pelvis",
                   "torque_limit": 2000.0, "segments": "... (docs/characters.md)"},
}


class Problem(BaseModel):
    detail: str = Field(description="what is wrong, naming the field and the rule")


class JobRequest(BaseModel):
    """A job request: the task spec as `spec`, with a seed, a PCA basis to search in, and
    where the search starts."""

    model_config = ConfigDict(extra="forbid")
    spec: TaskSpec
    seed: Annotated[int, Field(ge=0, lt=2**31, description=(
        f"CMA-ES seed; none: {DEFAULT_SEED}, the command line's default too"))] | None = None
    basis: Annotated[str, Field(max_length=64)] | None = None
    start: Literal["library", "cold"] | None = Field(
        "library", description="library: from the library's CMRT at the spec's task "
        "parameters when it has one (interpolated between neighbours or stored there), with a "
        "small step; cold: from the flat spline; none: library")


class JobBudget(BaseModel):
    """The most the job may cost (application.admission): evaluations x clip seconds."""

    evaluations: int
    clip_seconds: float
    sim_seconds: float
    ceiling_sim_seconds: float | None


class JobAccepted(BaseModel):
    id: str
    url: str
    status: str
    budget: JobBudget


class JobOut(BaseModel):
    id: str
    url: str
    name: str
    #: Where the search started: {"from": ..., "x0": [...]}; null: the flat spline.
    start: dict[str, Any] | None = None
    family: str
    task: str
    status: str
    stop_rule: str | None
    error: str | None
    seed: int | None
    basis_id: str | None
    created_at: datetime
    started_at: datetime | None
    finished_at: datetime | None
    best_objective: float | None
    best_params: list[float] | None
    evaluations: int
    iterations: int
    cancel_requested: bool
    cmrt_id: str | None = None
    links: dict[str, str]
    spec: dict[str, Any] | None = None
    #: `GET /jobs/{id}` only: the distinct numeric fingerprints of the processes that evaluated
    #: the job's candidates (more than one: workers whose bits may differ, docs/service.md).
    fingerprints: list[str] | None = None
    #: A robust job's (`optimize.robust`), once finished: the range it was optimised for and
    #: each variant's outcome of the best CMRT and of the flat spline (the result's block).
    robust: dict[str, Any] | None = None


class CancelAccepted(BaseModel):
    """A cancellation asked for (`POST /jobs/{id}/cancel`, `POST /families/{id}/cancel`): the
    driver stops the work at its next step; `status` is the state when it was asked."""

    id: str
    status: str
    cancel_requested: bool
    url: str


class JobPage(BaseModel):
    items: list[JobOut]
    total: int
    limit: int
    offset: int


class GenerationOut(BaseModel):
    iteration: int
    best: float
    median: float
    worst: float
    sigma: float
    best_so_far: float
    evaluations: int
    wall_time: float
    created_at: datetime


class GenerationPage(BaseModel):
    job_id: str
    status: str
    after: int
    last: int
    generations: list[GenerationOut]


class EvaluationSummary(BaseModel):
    """One generation's evaluations: how many in each state, and the attempts they took."""

    generation: int = Field(description="-1: the final re-evaluation (best and flat spline)")
    population: int
    done: int
    pending: int
    failed: int
    attempts: int
    repeated: int = Field(description="attempts beyond the first (a crashed or lost run)")


class EvaluationSummaryPage(BaseModel):
    job_id: str
    status: str
    after: int
    generations: list[EvaluationSummary]


class JobBest(BaseModel):
    """A job's best candidate so far, decoded on its spec (nulls before its first generation)."""

    job_id: str
    status: str
    iterations: int
    best_objective: float | None
    params: list[float] | None
    knot_times: list[float] | None
    values: list[float] | None = Field(description="horizontal knot values, m")
    vertical_values: list[float] | None = Field(description="vertical knot values, m (or null)")
    curve: dict[str, list[float]] | None = Field(
        description='{"t": [s], "dx": [m](, "dy": [m])}: the sampled curve')
    cmrt_id: str | None


class CmrtSummary(BaseModel):
    id: str
    url: str
    family: str
    task_parameters: dict[str, float]
    character: dict[str, Any]
    objective: float
    objective_without: float | None
    #: "search": the best candidate CMA-ES found; "flat": the flat spline (no anticipation)
    #: did better, so the entry is the flat spline.
    winner: str
    fell: bool
    job_id: str | None
    created_at: datetime
    curve: dict[str, Any] | None = Field(
        None, description="the sampled curve as GET /cmrts/{id} gives it; only with curves=true")


class CmrtPage(BaseModel):
    items: list[CmrtSummary]
    total: int
    limit: int
    offset: int


class LibraryFamily(BaseModel):
    family: str
    count: int


class LibraryFamilies(BaseModel):
    items: list[LibraryFamily]
    total: int


class BasisOut(BaseModel):
    id: str
    url: str
    family: str
    k: int
    mean: list[float]
    components: list[list[float]]
    variance_explained: list[float]
    members: list[str]
    box: Any = None
    created_at: datetime


class BasisPage(BaseModel):
    items: list[BasisOut]
    total: int
    limit: int
    offset: int


class CmrtClip(BaseModel):
    """The clip a library CMRT was optimised on, s."""

    preparation: float
    duration: float
    decay: float
    length: float


class CmrtSource(BaseModel):
    """Where a library CMRT came from: its job (null when imported) and the spec it was
    optimised on (null when stored without it)."""

    job_id: str | None
    job_url: str | None
    spec: dict[str, Any] | None


class CmrtOut(CmrtSummary):
    """One library CMRT with its spline and sampled curve."""

    clip: CmrtClip
    params: list[float]
    knot_times: list[float]
    values: list[Any] = Field(description="horizontal knot values, m; [dx, dy] pairs when the "
                                          "CMRT is vertical too")
    fell_without: bool | None
    source: CmrtSource


# ---- characters --------------------------------------------------------------------------
class CharacterRequest(BaseModel):
    """A character definition to keep by name (docs/characters.md: the schema, field by
    field); specs sent to the service name it as their `character.model`."""

    model_config = ConfigDict(extra="forbid")
    name: Annotated[str, Field(pattern=r"^[a-z0-9_]{1,64}$", strict=True,
                               description="lower-case letters, digits and `_`; no shipped "
                                           "character's name")]
    definition: Annotated[dict[str, Any], WithJsonSchema(
        {**definition_schema(), "description": "a full character definition (the rules that "
         "relate its fields to each other: docs/characters.md)"})]


class CharacterSummary(BaseModel):
    """A character in a few numbers, at its reference size."""

    height: float
    mass: float
    segments: int
    joints: list[str]
    hands: list[str]
    torso: str | None


class CharacterOut(BaseModel):
    """A character: `shipped` with the package, or `stored` by POST /characters (then with
    its creation time and the hash of its definition's canonical text)."""

    name: str
    url: str
    source: Literal["shipped", "stored"]
    summary: CharacterSummary
    definition: dict[str, Any] | None = None
    definition_hash: str | None = None
    created_at: datetime | None = None


class CharacterPage(BaseModel):
    """Stored characters by name (without their definitions), and the shipped ones' names."""

    items: list[CharacterOut]
    total: int
    limit: int
    offset: int
    shipped: list[str]


class BasisRequest(BaseModel):
    model_config = ConfigDict(extra="forbid")
    family: Annotated[str, Field(min_length=1, max_length=100)]
    k: Annotated[int, Field(ge=1, le=16)] = 3


# ---- the library's answers ----------------------------------------------------------------
class AnswerOutcome(BaseModel):
    """A served CMRT simulated at the query's value (kept in the library: `cached` when this
    query did not simulate it)."""

    status: str
    objective: float | None = None
    fell: bool | None = None
    fall_direction: str | None = None
    task_success: bool | None = None
    cpu_seconds: float | None = None
    error: str | None = None
    spec_hash: str
    cached: bool


class AnswerTry(BaseModel):
    """One CMRT the library simulated for an answer."""

    source: str
    members: list[str]
    outcome: AnswerOutcome


class AnswerSwitch(BaseModel):
    """The library's check of the two neighbours: detected when their spline parameters lie
    further apart (RMS, box units) than the threshold."""

    detected: bool
    distance: float
    threshold: float
    knot_shift: float
    between: list[dict[str, Any]]


class AnswerNeighbour(BaseModel):
    model_config = ConfigDict(extra="allow")
    id: str
    objective: float
    task_parameters: dict[str, float]
    url: str | None = None


class LibraryAnswer(BaseModel):
    """What the library serves at a task parameter, and what it is."""

    family: str
    key: str
    value: float
    note: str | None = None
    source: Literal["member", "interpolated", "refined", "robust"]
    members: list[str]
    neighbours: list[AnswerNeighbour]
    weight: float
    exact: bool
    extrapolated: bool
    switch: AnswerSwitch | None
    predicted_objective: float
    verified: bool
    verdict: Literal["unverified", "good", "weak", "falls", "fails_task", "failed"]
    outcome: AnswerOutcome | None
    tried: list[AnswerTry]
    message: str
    refine: dict[str, Any] | None = None
    #: A robust CMRT covering the value (`source: robust`): its id, the varied path, the range,
    #: the variants and the aggregate it was optimised for.
    robust: dict[str, Any] | None = None
    length: float
    knot_times: list[float]
    values: list[float]
    vertical_values: list[float] | None
    curve: dict[str, list[float]]


class RefineRequest(BaseModel):
    """A refinement at a task parameter: `parameters` names the value (one key, or several
    with `along`), searched in the family's newest PCA basis (or `basis`)."""

    # several parameters: `along` names the interpolated one (which must be one of them, a
    # rule JSON Schema cannot state)
    model_config = ConfigDict(extra="forbid", json_schema_extra={
        "if": {"properties": {"parameters": {"minProperties": 2}}, "required": ["parameters"]},
        "then": {"properties": {"along": {"type": "string"}}, "required": ["along"]}})
    family: Annotated[str, Field(min_length=1, max_length=100)]
    parameters: Annotated[dict[Annotated[str, Field(min_length=1, max_length=64)],
                               Annotated[float, Field(allow_inf_nan=False)]],
                          Field(min_length=1, max_length=16)]
    along: Annotated[str, Field(min_length=1, max_length=64)] | None = None
    basis: Annotated[str, Field(min_length=1, max_length=64)] | None = None
    max_evaluations: Annotated[int, Field(ge=1, le=1000)] = 150
    seed: Annotated[int, Field(ge=0, lt=2**31)] = DEFAULT_SEED
    extrapolate: bool = False


class RefineAccepted(BaseModel):
    id: str
    url: str
    status: str
    budget: JobBudget
    basis_id: str
    start: dict[str, Any]
    answer: LibraryAnswer


REFINE_EXAMPLE: dict[str, Any] = {"family": "domino", "parameters": {"mass": 45}}


# ---- families (service.routers.families; docs/families.md) ---------------------------------
class FamilyAccepted(BaseModel):
    id: str
    url: str
    status: str
    runs: int = Field(description="runs of the family's plan (members, references, reduced "
                                  "runs, the probes)")
    budget: JobBudget = Field(description="the whole family's: the sum over its runs")


class FamilyLinks(BaseModel):
    cancel: str
    dashboard: str


class FamilyOut(BaseModel):
    """A family; `GET /families/{id}` adds its request, runs and progress, and once done the
    members, the PCA basis and the checks (docs/families.md)."""

    id: str
    url: str
    family: str
    param: str
    status: str
    error: str | None
    cancel_requested: bool
    created_at: datetime
    finished_at: datetime | None
    values: list[float] | None
    strategy: str | None
    links: FamilyLinks
    spec: dict[str, Any] | None = Field(None, description="the family request as stored")
    runs: list[FamilyRunOut] | None = None
    progress: FamilyProgress | None = None
    members: list[dict[str, Any]] | None = None
    basis: dict[str, Any] | None = None
    checks: dict[str, Any] | None = None
    paper_table2: list[dict[str, Any]] | None = Field(
        None, description="the paper's Table 2 rows where the task has one")


class FamilyPage(BaseModel):
    items: list[FamilyOut]
    total: int
    limit: int
    offset: int


# ---- operations --------------------------------------------------------------------------
class Health(BaseModel):
    """`GET /health` (200; a degraded state is a 503 with `detail`)."""

    status: Literal["ok", "degraded"]
    database: str = Field(description='"ok" or "error"')
    broker: str = Field(description='"ok", "error", or "none (embedded local process pool)"')
    executor: str
    drivers: int = Field(description="jobs and families this process drives now")
    fingerprints: dict[str, str] = Field(
        default_factory=dict,
        description='numeric fingerprint per process: "api" (this process) and every live '
                    "Celery worker by hostname")
    mixed: bool = Field(False, description="more than one fingerprint: the fleet's results "
                                           "may differ in their last bits")
    detail: str | None = Field(None, description="what is unreachable (degraded only)")


# ---- what-if simulations (the request models are application.simulations') -------------
class SimulationOut(BaseModel):
    """`status` "done" with the outcome, or "failed" with `error` (the simulation diverged, its
    process died, or it ran past the time limit)."""

    status: Literal["done", "failed"]
    error: str | None = None
    cmrt: dict[str, Any] | None = None
    objective: float | None = None
    fell: bool | None = None
    fall_time: float | None = None
    fall_reason: str | None = None
    fall_direction: Literal["forward", "backward"] | None = None
    task_success: bool | None = None
    task_penalty: float | None = None
    error_norm: float | None = None
    max_abs_error: float | None = None
    sim_seconds: float | None = None
    cpu_seconds: float | None = None
    steps: int | None = None
    contact_steps: int | None = None
    cmrt_released_at: float | None = Field(
        None, description="when (s) the CMRT was released because the task reported that the "
                          "interaction it anticipates failed (a missed punch); null: held")
    traces: dict[str, list[Any]] | None = None
    frames: dict[str, Any] | None = None


SIMULATION_EXAMPLE: dict[str, Any] = {"spec": JOB_EXAMPLE, "cmrt": None, "traces": False}


# ---- replays (service.routers.replays; the document is sim.replay's, docs/replay.md) ----------
class ReplayOut(BaseModel):
    """A replay document, schema `cmrt-replay/1` (docs/replay.md): the character's shapes to
    scale, the props, and per clip the 100 Hz poses, CM, CM reference, CP, support and plot
    traces with the clip's outcome."""

    model_config = ConfigDict(populate_by_name=True)
    schema_name: Literal["cmrt-replay/1"] = Field(alias="schema")
    spec: dict[str, Any]
    rate: float = Field(description="frames per simulated second")
    character: dict[str, Any]
    props: list[dict[str, Any]]
    bodies: list[str] = Field(description="names of the pose rows: bodies, props, chain links")
    clips: list[dict[str, Any]]


REPLAY_EXAMPLE: dict[str, Any] = {"spec": JOB_EXAMPLE, "cmrt": None, "compare": True}


# ---- signed links (service.routers.links, service.links) --------------------------------------
class LinkRequest(BaseModel):
    """A replay page or a job's motion file to open without the token header."""

    model_config = ConfigDict(extra="forbid")
    path: str = Field(max_length=128,
                      description="`/jobs/{id}/replay` or `/cmrts/{id}/replay` of an existing "
                                  "job or library CMRT, or `/jobs/{id}/motion.bvh` or "
                                  "`/jobs/{id}/motion.csv` of an existing job (id: 1-64 of "
                                  "A-Z a-z 0-9 . _ ~ -)",
                      json_schema_extra={"pattern": f"^(?:{SIGNABLE.pattern})$"})

    @field_validator("path")
    @classmethod
    def _signable(cls, path: str) -> str:
        # said in words: the pattern in the schema would read as a regular expression
        if not SIGNABLE.fullmatch(path):
            raise ValueError("must be a replay page, /jobs/{id}/replay or /cmrts/{id}/replay, "
                             "or a job's motion file, /jobs/{id}/motion.bvh or .csv (id: 1-64 "
                             "of A-Z a-z 0-9 . _ ~ -)")
        return path


class LinkOut(BaseModel):
    """A signed link to `path`; valid until `expires` (unix seconds; null: no token is set,
    the plain path opens as it is)."""

    url: str
    expires: int | None


LINK_EXAMPLE: dict[str, Any] = {"path": "/jobs/0123abcd/replay"}
