"""A small Python client of the CMRT HTTP API (stdlib, httpx and PyYAML only), for scripts and
notebooks, and the code behind `cmrt submit / jobs / watch / library`.

    from cmrt.client import Client
    c = Client("http://127.0.0.1:8000")              # token=... when CMRT_API_TOKEN is set
    job = c.submit("examples/fast_bend.yaml", seed=1)  # a path (YAML/JSON) or a spec dict
    final = job.wait(on_progress=print)               # polls; returns the finished job body
    job.best()                                        # objective, params, library CMRT
    c.cmrts(family="bend", duration=0.4)              # library entries by task parameters
    c.interpolate(family="bend", duration=0.5)

It uses only the endpoints documented in docs/service.md and the README. Every 4xx/5xx answer
raises an `ApiError` (a subclass per kind) carrying the server's `detail` and the field it
names; a server that cannot be reached raises `ServiceUnreachableError`. Nothing here imports the
simulator, the optimiser or the server.
"""

from __future__ import annotations

import json
import re
import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import httpx

from cmrt.specfile import SpecReadError, read_document, read_spec_file

#: Job states after which nothing changes any more.
TERMINAL_STATUSES = ("converged", "stopped", "failed", "cancelled")
#: Job states of a job that finished with a result (the others ended without one).
SUCCESS_STATUSES = ("converged", "stopped")
#: Seconds between two polls of `Job.wait`.
DEFAULT_POLL_SECONDS = 0.5
#: Seconds one HTTP request may take (a what-if simulation runs a whole clip: longer).
DEFAULT_TIMEOUT_SECONDS = 30.0
SIMULATION_TIMEOUT_SECONDS = 660.0

# "spec: clip.preparation: must be >= 0" -> field "spec.clip.preparation", rule "must be >= 0"
_FIELD_PART = re.compile(r"[A-Za-z_][\w\-]*(?:\[\d+\])?(?:\.[A-Za-z_0-9][\w\-]*(?:\[\d+\])?)*")


class ClientError(Exception):
    """Anything the client cannot do; the message is meant for a person."""


class ServiceUnreachableError(ClientError):
    """No answer from the service (refused, DNS, timeout): the URL is in the message."""


class SpecFileError(ClientError):
    """A spec file that cannot be read or parsed (before anything is sent)."""


class WaitTimeoutError(ClientError):
    """`Job.wait(timeout=...)` ran out before the job finished."""


class ApiError(ClientError):
    """An error answer of the API: `status`, the server's `detail` (`"<field>: <rule>"`),
    and `field` / `rule` split from it (`field` is None when the detail names none)."""

    def __init__(self, status: int, detail: str, method: str = "", url: str = "") -> None:
        self.status = status
        self.detail = detail
        self.method = method
        self.url = url
        self.field, self.rule = split_detail(detail)
        super().__init__(detail)

    def __str__(self) -> str:
        return f"{self.detail} (HTTP {self.status} from {self.method} {self.url})"


class InvalidRequestError(ApiError):
    """400 / 413 / 415 / 422: the request (a spec, a parameter) broke a rule; nothing stored."""


class UnauthorizedError(ApiError):
    """401 / 403: token missing or wrong (set `token=`, or CMRT_API_TOKEN for the CLI)."""


class NotFoundError(ApiError):
    """404: no such job, CMRT, basis or path."""


class ConflictError(ApiError):
    """409: the resource's state forbids it (e.g. cancelling a finished job)."""


class ServiceBusyError(ApiError):
    """503: the service is busy or degraded; `retry_after` seconds if it said."""

    retry_after: float | None = None


_ERROR_CLASSES: dict[int, type[ApiError]] = {
    400: InvalidRequestError, 413: InvalidRequestError, 415: InvalidRequestError,
    422: InvalidRequestError, 401: UnauthorizedError, 403: UnauthorizedError,
    404: NotFoundError, 409: ConflictError, 503: ServiceBusyError,
}


def split_detail(detail: str) -> tuple[str | None, str]:
    """`"spec: clip.preparation: must be >= 0"` -> `("spec.clip.preparation", "must be >= 0")`;
    a detail without a leading field name gives `(None, detail)`."""
    parts = detail.split(": ")
    names = []
    for p in parts[:-1]:
        if not _FIELD_PART.fullmatch(p):
            break
        names.append(p)
    if not names:
        return None, detail
    return ".".join(names), ": ".join(parts[len(names):])


def load_spec_file(path: str | Path) -> dict[str, Any]:
    """The task spec in a YAML or JSON file, as a dict, with the blocks it takes from other
    files inline (`cmrt.specfile`; validation is the server's)."""
    try:
        return read_spec_file(path)
    except SpecReadError as err:
        raise SpecFileError(str(err)) from None


def _parse_time(value: str | None) -> datetime | None:
    if not value:
        return None
    t = datetime.fromisoformat(value)
    return t if t.tzinfo else t.replace(tzinfo=UTC)  # the store keeps UTC


@dataclass(frozen=True)
class Progress:
    """One look at a job while it runs (what `Job.wait`'s `on_progress` receives).

    `max_evaluations`: the spec's cap (the progress bar's total); `best`: the best objective
    so far (None before the first generation); `elapsed`: seconds since the job started (by
    the server's clock, until it finished); `new`: the generations since the last look."""

    job_id: str
    status: str
    generation: int | None
    evaluations: int
    max_evaluations: int | None
    best: float | None
    sigma: float | None
    elapsed: float
    new: tuple[dict[str, Any], ...] = ()
    started_at: datetime | None = None

    @property
    def done(self) -> bool:
        return self.status in TERMINAL_STATUSES

    def line(self) -> str:
        """The plain progress line (the format `cmrt optimize` has always printed)."""
        return format_line(self.generation, self.evaluations, self.best, self.sigma,
                           self.elapsed)

    def generation_lines(self) -> list[str]:
        """One plain line per new generation, elapsed at the time it was stored."""
        out = []
        for g in self.new:
            made = _parse_time(g.get("created_at"))
            elapsed = (max(0.0, (made - self.started_at).total_seconds())
                       if made and self.started_at else self.elapsed)
            out.append(format_line(g["iteration"], g["evaluations"], g["best_so_far"],
                                   g["sigma"], elapsed))
        return out


def format_line(generation: int | None, evaluations: int, best: float | None,
                sigma: float | None, elapsed: float) -> str:
    """`gen    2  evals    24  best    2.8268  sigma  0.1454     17.1 s` (generation index
    from 0: the third generation of 8 candidates)."""
    gen = -1 if generation is None else generation
    best = float("nan") if best is None else best
    sigma = float("nan") if sigma is None else sigma
    return (f"gen {gen:4d}  evals {evaluations:5d}  best {best:9.4f}  "
            f"sigma {sigma:7.4f}  {elapsed:7.1f} s")


class Job:
    """A job of the service. `data` is the last body fetched (GET /jobs/{id})."""

    def __init__(self, client: Client, job_id: str, data: Mapping[str, Any] | None = None,
                 budget: Mapping[str, Any] | None = None) -> None:
        self.client = client
        self.id = job_id
        self.data: dict[str, Any] = dict(data or {})
        #: The 202's budget (submit only): the most evaluations and simulated seconds.
        self.budget = dict(budget) if budget else None
        self._last_generation = -1
        self._gen: dict[str, Any] | None = None
        #: A refinement's (Client.refine): the answer it started from, and its start.
        self.answer: dict[str, Any] | None = None
        self.start: dict[str, Any] | None = None

    def __repr__(self) -> str:
        return f"Job({self.id!r}, status={self.data.get('status')!r})"

    @property
    def url(self) -> str:
        return f"{self.client.url}/jobs/{self.id}"

    def refresh(self) -> dict[str, Any]:
        """Fetch the job's body (status, best, evaluations, cmrt_id, spec) and keep it."""
        self.data = self.client._request("GET", f"/jobs/{self.id}")
        return self.data

    def status(self) -> str:
        """The job's state now: queued, running, converged, stopped, failed or cancelled."""
        return self.refresh()["status"]

    def generations(self, after: int | None = None) -> list[dict[str, Any]]:
        """The stored generations (iteration, best, median, worst, sigma, best_so_far,
        evaluations, wall_time, created_at), only those after iteration `after` if given."""
        params = {} if after is None else {"after": after}
        return self.client._request("GET", f"/jobs/{self.id}/generations",
                                    params=params)["generations"]

    def evaluations(self) -> list[dict[str, Any]]:
        """Per generation: population, done / pending / failed, attempts, repeated."""
        return self.client._request("GET", f"/jobs/{self.id}/evaluations")["generations"]

    def cancel(self) -> dict[str, Any]:
        """Ask the service to cancel the job (raises ConflictError if it already finished)."""
        return self.client._request("POST", f"/jobs/{self.id}/cancel")

    def best(self) -> dict[str, Any]:
        """The best candidate so far: `objective`, `params`, `evaluations`, `status`, and for a
        finished job the library entry it added (`cmrt`, with `winner`: "search" or "flat",
        and `objective_without`, the flat spline's objective)."""
        d = self.refresh()
        out: dict[str, Any] = {"status": d["status"], "objective": d["best_objective"],
                               "params": d["best_params"], "evaluations": d["evaluations"],
                               "cmrt_id": d.get("cmrt_id"), "cmrt": None}
        if d.get("cmrt_id"):
            out["cmrt"] = self.client.cmrt(d["cmrt_id"])
        return out

    def motion(self, fmt: str = "bvh", fps: float | None = None,
               out: str | Path | None = None) -> str:
        """The best candidate so far as a motion file (GET /jobs/{id}/motion.bvh or .csv,
        docs/export.md): `fmt` "bvh" (the character's skeleton) or "csv" (root, joint angles,
        CM, CP), at `fps` frames per second (the service's default 60 when None). The text;
        also written to `out` when given. NotFoundError while the job has no candidate."""
        if fmt not in ("bvh", "csv"):
            raise ValueError(f"fmt: must be 'bvh' or 'csv', got {fmt!r}")
        params = {} if fps is None else {"fps": fps}
        text = self.client._text("GET", f"/jobs/{self.id}/motion.{fmt}", params=params)
        if out is not None:
            Path(out).write_text(text, encoding="utf-8")
        return text

    def progress(self) -> Progress:
        """One look: the job's body and the generations since the last look."""
        d = self.refresh()
        new = self.generations(after=self._last_generation)
        if new:
            self._last_generation = new[-1]["iteration"]
            self._gen = new[-1]
        started, finished = _parse_time(d.get("started_at")), _parse_time(d.get("finished_at"))
        end = finished or datetime.now(UTC)
        elapsed = max(0.0, (end - started).total_seconds()) if started else 0.0
        spec = d.get("spec") or {}
        cap = (spec.get("optimize") or {}).get("max_evaluations")
        g = self._gen
        return Progress(job_id=self.id, status=d["status"],
                        generation=None if g is None else g["iteration"],
                        evaluations=d["evaluations"],
                        max_evaluations=cap if isinstance(cap, int) else None,
                        best=d["best_objective"], sigma=None if g is None else g["sigma"],
                        elapsed=elapsed, new=tuple(new), started_at=started)

    def wait(self, timeout: float | None = None,
             on_progress: Callable[[Progress], Any] | None = None,
             poll: float = DEFAULT_POLL_SECONDS) -> dict[str, Any]:
        """Poll until the job is finished and return its body; `on_progress(Progress)` is
        called after every poll (only new generations are fetched, `?after=`). Raises
        WaitTimeoutError after `timeout` seconds (the job goes on running)."""
        t0 = time.monotonic()
        while True:
            p = self.progress()
            if on_progress is not None:
                on_progress(p)
            if p.done:
                return self.data
            if timeout is not None and time.monotonic() - t0 >= timeout:
                raise WaitTimeoutError(f"job {self.id} still {p.status} after {timeout:g} s")
            time.sleep(poll)


class Family:
    """A family of the service (POST /families). `data` is the last body fetched."""

    def __init__(self, client: Client, family_id: str, data: Mapping[str, Any] | None = None,
                 budget: Mapping[str, Any] | None = None) -> None:
        self.client = client
        self.id = family_id
        self.data: dict[str, Any] = dict(data or {})
        #: The 202's budget (submit only): the most evaluations and simulated seconds in all.
        self.budget = dict(budget) if budget else None

    def __repr__(self) -> str:
        return f"Family({self.id!r}, status={self.data.get('status')!r})"

    @property
    def url(self) -> str:
        return f"{self.client.url}/families/{self.id}"

    def refresh(self, curves: bool = False) -> dict[str, Any]:
        """Fetch the family: status, progress, runs and their jobs; once done its members,
        basis and checks (`curves=True`: each run's [evaluations, best so far])."""
        self.data = self.client._request("GET", f"/families/{self.id}",
                                         params={"curves": "true"} if curves else None)
        return self.data

    def status(self) -> str:
        """running, done, failed or cancelled."""
        return self.refresh()["status"]

    def cancel(self) -> dict[str, Any]:
        """Cancel the family's unfinished runs; it ends `cancelled`."""
        return self.client._request("POST", f"/families/{self.id}/cancel")

    def wait(self, timeout: float | None = None,
             on_progress: Callable[[dict[str, Any]], Any] | None = None,
             poll: float = DEFAULT_POLL_SECONDS) -> dict[str, Any]:
        """Poll until the family has finished and return its body; `on_progress(body)` after
        every poll. Raises WaitTimeoutError after `timeout` s (the family goes on)."""
        t0 = time.monotonic()
        while True:
            d = self.refresh()
            if on_progress is not None:
                on_progress(d)
            if d["status"] != "running":
                return d
            if timeout is not None and time.monotonic() - t0 >= timeout:
                raise WaitTimeoutError(f"family {self.id} still running after {timeout:g} s")
            time.sleep(poll)


class Client:
    """The CMRT service at `url` (e.g. http://127.0.0.1:8000); `token`: the bearer token when
    the service sets CMRT_API_TOKEN."""

    def __init__(self, url: str, token: str | None = None,
                 timeout: float = DEFAULT_TIMEOUT_SECONDS,
                 transport: httpx.BaseTransport | None = None) -> None:
        if not re.match(r"^https?://[^\s/?#]+", url or ""):
            raise ClientError(f"url: must be http(s)://host[:port][/path], got {url!r}")
        self.url = url.rstrip("/")
        headers = {"Accept": "application/json"}
        if token:
            headers["Authorization"] = f"Bearer {token}"
        self._http = httpx.Client(base_url=self.url, headers=headers, timeout=timeout,
                                  transport=transport)

    def __enter__(self) -> Client:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def close(self) -> None:
        self._http.close()

    def __repr__(self) -> str:
        return f"Client({self.url!r})"

    # ---- transport ---------------------------------------------------------------------
    def _request(self, method: str, path: str, *, params: Mapping[str, Any] | None = None,
                 json_body: Any = None, timeout: float | None = None) -> Any:
        """The JSON answer of a request (ApiError and its kinds for a 4xx or 5xx)."""
        r = self._send(method, path, params=params, json_body=json_body, timeout=timeout)
        try:
            return r.json()
        except ValueError:
            raise ClientError(f"{method} {path}: the answer is not JSON (HTTP "
                              f"{r.status_code}, {r.headers.get('content-type')}); is "
                              f"{self.url} a CMRT service?") from None

    def _text(self, method: str, path: str, *, params: Mapping[str, Any] | None = None) -> str:
        """The text answer of a request (a file the service writes: a motion)."""
        return self._send(method, path, params=params).text

    def _send(self, method: str, path: str, *, params: Mapping[str, Any] | None = None,
              json_body: Any = None, timeout: float | None = None) -> httpx.Response:
        kwargs: dict[str, Any] = {}
        if params:
            kwargs["params"] = {k: _query_value(v) for k, v in params.items() if v is not None}
        if json_body is not None:
            kwargs["content"] = json.dumps(json_body, allow_nan=False)
            kwargs["headers"] = {"Content-Type": "application/json"}
        if timeout is not None:
            kwargs["timeout"] = timeout
        try:
            try:
                r = self._http.request(method, path, **kwargs)
            except httpx.RemoteProtocolError:
                # A kept-alive connection the server closed as the request went out (its
                # idle timeout): a read is sent once more on a new connection.
                if method not in ("GET", "HEAD"):
                    raise
                r = self._http.request(method, path, **kwargs)
        except httpx.TimeoutException:
            raise ServiceUnreachableError(f"the CMRT service at {self.url} did not answer "
                                     f"{method} {path} in time") from None
        except httpx.TransportError as err:
            raise ServiceUnreachableError(f"cannot reach the CMRT service at {self.url} "
                                     f"({type(err).__name__}: {err}); is `cmrt serve` "
                                     "running there? (--url / CMRT_URL)") from None
        if r.status_code >= 400:
            raise _api_error(r, method, path)
        return r

    # ---- endpoints ---------------------------------------------------------------------
    def health(self) -> dict[str, Any]:
        """GET /health: database and broker state (raises ServiceBusyError when degraded)."""
        return self._request("GET", "/health")

    def submit(self, spec_or_path: Mapping[str, Any] | str | Path, seed: int | None = None,
               name: str | None = None, basis: str | None = None) -> Job:
        """POST /jobs: optimise a task spec (a dict, or the path of a YAML/JSON file);
        `name` replaces the spec's name, `basis` a PCA basis id to search in."""
        spec = (load_spec_file(spec_or_path) if isinstance(spec_or_path, (str, Path))
                else dict(spec_or_path))
        if name is not None:
            spec["name"] = name
        body: dict[str, Any] = {"spec": spec}
        if seed is not None:
            body["seed"] = seed
        if basis is not None:
            body["basis"] = basis
        out = self._request("POST", "/jobs", json_body=body)
        return Job(self, out["id"], {"id": out["id"], "status": out["status"],
                                     "name": spec.get("name")},
                   budget=out.get("budget"))

    def submit_family(self, request: Mapping[str, Any]) -> Family:
        """POST /families: grow a family of CMRTs (docs/families.md): `request` holds the base
        `spec` (a dict, or the path of a YAML/JSON file), `param`, `values`, `strategy`,
        `from`, `warm`, `leave_out`, `k`, `seed`."""
        body = dict(request)
        if isinstance(body.get("spec"), (str, Path)):
            body["spec"] = load_spec_file(body["spec"])
        out = self._request("POST", "/families", json_body=body)
        return Family(self, out["id"], {"id": out["id"], "status": out["status"]},
                      budget=out.get("budget"))

    def family(self, family_id: str) -> Family:
        """The family with this id (fetched now: raises NotFoundError if there is none)."""
        f = Family(self, family_id)
        f.refresh()
        return f

    def families(self, status: str | None = None, limit: int = 50,
                 offset: int = 0) -> list[Family]:
        """GET /families: newest first."""
        page = self._request("GET", "/families", params={"status": status, "limit": limit,
                                                         "offset": offset})
        return [Family(self, d["id"], d) for d in page["items"]]

    def job(self, job_id: str) -> Job:
        """The job with this id (fetched now: raises NotFoundError if there is none)."""
        j = Job(self, job_id)
        j.refresh()
        return j

    def jobs(self, status: str | None = None, family: str | None = None,
             limit: int = 50, offset: int = 0) -> list[Job]:
        """GET /jobs: newest first, filtered by status and task family."""
        page = self._request("GET", "/jobs", params={"status": status, "family": family,
                                                     "limit": limit, "offset": offset})
        return [Job(self, d["id"], d) for d in page["items"]]

    def cmrts(self, family: str | None = None, tolerance: float | None = None,
              limit: int = 50, offset: int = 0, **params: float) -> list[dict[str, Any]]:
        """GET /cmrts: library entries of a family; with task parameters (`duration=0.4`) the
        exact matches, or with `tolerance` the nearest first within +-tolerance."""
        query: dict[str, Any] = {"family": family, "tolerance": tolerance, "limit": limit,
                                 "offset": offset, **params}
        return self._request("GET", "/cmrts", params=query)["items"]

    def cmrt(self, cmrt_id: str) -> dict[str, Any]:
        """GET /cmrts/{id}: one library CMRT with knots, values, sampled curve and source."""
        return self._request("GET", f"/cmrts/{cmrt_id}")

    def interpolate(self, family: str, along: str | None = None, extrapolate: bool = False,
                    verify: bool = False, **params: float) -> dict[str, Any]:
        """GET /cmrts/interpolate: the library's answer at task parameter values
        (`duration=0.5`, or a spec path: `**{"task.mass": 45}`) and what it is: `source`
        (member, interpolated, refined), `members`, the neighbours' `switch` check; with
        `verify=True` simulated once (then kept by the library): `outcome`, `verdict` ("good",
        "weak", "falls", "fails_task", "failed") and `message`. `along` names the interpolated
        parameter when several are given; the others must match."""
        query: dict[str, Any] = {"family": family, "along": along,
                                 "extrapolate": extrapolate or None,
                                 "verify": verify or None, **params}
        return self._request("GET", "/cmrts/interpolate", params=query)

    def refine(self, family: str, along: str | None = None, basis: str | None = None,
               max_evaluations: int | None = None, seed: int | None = None,
               extrapolate: bool = False, **params: float) -> Job:
        """POST /refinements: a job searching the family's PCA basis (the newest, or `basis`)
        from the library's best answer at the task parameter values; its result joins the
        library. The returned job's `answer` is the answer it started from."""
        body: dict[str, Any] = {"family": family, "parameters": params}
        for k, v in (("along", along), ("basis", basis), ("max_evaluations", max_evaluations),
                     ("seed", seed)):
            if v is not None:
                body[k] = v
        if extrapolate:
            body["extrapolate"] = True
        out = self._request("POST", "/refinements", json_body=body)
        job = Job(self, out["id"], {"id": out["id"], "status": out["status"],
                                    "name": out["answer"]["family"]},
                  budget=out.get("budget"))
        job.answer = out["answer"]
        job.start = out["start"]
        return job

    def add_character(self, name: str,
                      definition: Mapping[str, Any] | str | Path) -> dict[str, Any]:
        """POST /characters: keep a character definition (a mapping, or the path of a YAML or
        JSON character file) under `name`; specs sent to the service may then name it as
        their `character.model`. InvalidRequestError names the field of a bad definition,
        ConflictError a taken name (a shipped or stored character's)."""
        if isinstance(definition, (str, Path)):
            try:
                definition = read_document(definition, "character")
            except SpecReadError as err:
                raise SpecFileError(str(err)) from None
        return self._request("POST", "/characters",
                             json_body={"name": name, "definition": definition})

    def characters(self, limit: int = 50, offset: int = 0) -> dict[str, Any]:
        """GET /characters: the stored characters by name (`items`, each with its `summary`)
        and the shipped ones' names (`shipped`)."""
        return self._request("GET", "/characters", params={"limit": limit, "offset": offset})

    def character(self, name: str) -> dict[str, Any]:
        """GET /characters/{name}: a stored or shipped character with its definition."""
        return self._request("GET", f"/characters/{name}")

    def basis(self, family: str, k: int) -> dict[str, Any]:
        """POST /bases: a PCA basis of the family's library CMRTs."""
        return self._request("POST", "/bases", json_body={"family": family, "k": k})

    def simulate(self, spec_or_path: Mapping[str, Any] | str | Path, *,
                 cmrt: str | None = None, job: str | Job | None = None,
                 params: list[float] | None = None, traces: bool = False,
                 frames: bool = False) -> dict[str, Any]:
        """POST /simulations: one clip of a spec with a library CMRT (`cmrt=` id), a job's best
        candidate (`job=`), inline spline parameters in [0, 1] (`params=`), or none of them
        (no anticipation). Returns objective, fell, fall_direction, task_success, ..."""
        given = [x is not None for x in (cmrt, job, params)]
        if sum(given) > 1:
            raise ClientError("simulate: give at most one of cmrt=, job=, params=")
        spec = (load_spec_file(spec_or_path) if isinstance(spec_or_path, (str, Path))
                else dict(spec_or_path))
        choice: dict[str, Any] | None = None
        if cmrt is not None:
            choice = {"source": "library", "id": cmrt}
        elif job is not None:
            choice = {"source": "job", "id": job.id if isinstance(job, Job) else job}
        elif params is not None:
            choice = {"source": "params", "params": [float(v) for v in params]}
        return self._request("POST", "/simulations", timeout=SIMULATION_TIMEOUT_SECONDS,
                             json_body={"spec": spec, "cmrt": choice, "traces": traces,
                                        "frames": frames})


def _query_value(v: Any) -> Any:
    if isinstance(v, bool):
        return "true" if v else "false"
    return v


def _api_error(r: httpx.Response, method: str, path: str) -> ApiError:
    try:
        body = r.json()
        detail = body["detail"] if isinstance(body, dict) else str(body)
        if not isinstance(detail, str):
            detail = json.dumps(detail)
    except (ValueError, KeyError):
        detail = r.text.strip()[:500] or r.reason_phrase
    cls = _ERROR_CLASSES.get(r.status_code, ApiError)
    err = cls(r.status_code, detail, method, path)
    if isinstance(err, ServiceBusyError) and r.headers.get("retry-after", "").isdigit():
        err.retry_after = float(r.headers["retry-after"])
    return err
