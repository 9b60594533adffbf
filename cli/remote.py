"""The client commands of `cmrt`: submit, jobs, watch, library (talking to a running service
through `cmrt.client`).

The service URL is `--url`, else the settings' `client_url` (CMRT_URL, else CMRT_PUBLIC_URL,
else http://CMRT_API_HOST:CMRT_API_PORT); the bearer token is CMRT_API_TOKEN. Exit status:
0 done (a waited-for job converged or stopped at its cap), 1 a waited-for job failed or was
cancelled, or the service answered 5xx, 2 bad input (an argument, a spec file, any 4xx answer,
whose message names the field and the rule), 3 the service cannot be reached.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from collections.abc import Callable
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

from cmrt.cmdline import EXIT_BAD_INPUT, die
from cmrt.defaults import DEFAULT_SEED

EXIT_JOB_FAILED = 1
EXIT_UNREACHABLE = 3


def _client(args: argparse.Namespace) -> Any:
    from cmrt.client import Client
    from cmrt.settings import get_settings

    settings = get_settings()
    token = settings.api_token.get_secret_value() if settings.api_token else None
    return Client(args.url or settings.client_url, token=token)


def _guard(fn: Callable[[argparse.Namespace], int]) -> Callable[[argparse.Namespace], int]:
    """Client errors become one line on stderr and an exit status (module docstring)."""

    def run(args: argparse.Namespace) -> int:
        from pydantic import ValidationError

        from cmrt import client as c

        try:
            return fn(args)
        except c.ServiceUnreachableError as err:
            return die(str(err), EXIT_UNREACHABLE)
        except (c.InvalidRequestError, c.UnauthorizedError, c.NotFoundError,
                c.ConflictError) as err:
            return die(err.detail, EXIT_BAD_INPUT)
        except c.ApiError as err:
            return die(str(err), EXIT_JOB_FAILED)
        except c.SpecFileError as err:
            return die(str(err), EXIT_BAD_INPUT)
        except c.ClientError as err:  # a bad --url, an answer that is not the API's
            return die(str(err), EXIT_BAD_INPUT)
        except ValidationError as err:  # CMRT_* settings that break a rule
            first = err.errors()[0]
            loc = ".".join(str(p) for p in first["loc"])
            return die(f"settings: CMRT_{loc.upper()}: {first['msg']}", EXIT_BAD_INPUT)

    run.__name__ = fn.__name__
    run.__doc__ = fn.__doc__
    return run


def _f(v: Any, fmt: str = ".4f") -> str:
    if isinstance(v, float) and math.isfinite(v):
        return format(v, fmt)
    return "-" if v is None else str(v)


def _elapsed(d: dict[str, Any]) -> str:
    from cmrt.client import _parse_time

    start, end = _parse_time(d.get("started_at")), _parse_time(d.get("finished_at"))
    if start is None:
        return "-"
    return f"{((end or datetime.now(UTC)) - start).total_seconds():.1f}"


def _summary(client: Any, d: dict[str, Any]) -> list[str]:
    """What a finished job gave: state, best against the flat spline, its library CMRT."""
    lines = [f"job {d['id']} {d['status']}"
             + (f" ({d['stop_rule']})" if d.get("stop_rule") else "")
             + f": {d['evaluations']} evaluations, {d['iterations']} generations, "
             f"{_elapsed(d)} s"]
    if d.get("error"):
        lines.append(f"error: {d['error']}")
    if d.get("cmrt_id"):
        e = client.cmrt(d["cmrt_id"])
        flat, best = e.get("objective_without"), d.get("best_objective")
        if e["winner"] == "search" and isinstance(flat, float) and flat > 0:
            verdict = f"{100.0 * (flat - e['objective']) / flat:.1f} % below the flat spline"
        else:
            verdict = "the flat spline is better: no anticipation learned"
        lines.append(f"best candidate {_f(best)}; flat spline {_f(flat)} "
                     f"({'falls' if e.get('fell_without') else 'stands'}): {verdict}")
        lines.append(f"library CMRT {e['id']} ({e['winner']}): objective {_f(e['objective'])}"
                     f", {'falls' if e['fell'] else 'stands'}")
    elif d.get("best_objective") is not None:
        lines.append(f"best candidate {_f(d['best_objective'])}")
    return lines


def _follow(client: Any, job: Any, title: str, as_json: bool) -> int:
    from cli.progress import ProgressDisplay
    from cmrt.client import SUCCESS_STATUSES

    # The bar on stderr when stdout carries JSON; on stdout otherwise (cmrt watch's output).
    stream = sys.stderr if as_json else sys.stdout
    with ProgressDisplay(stream, title) as show:
        final = job.wait(on_progress=show)
    if as_json:
        print(json.dumps(final))
    else:
        for line in _summary(client, final):
            print(line)
    return 0 if final["status"] in SUCCESS_STATUSES else EXIT_JOB_FAILED


@_guard
def cmd_submit(args: argparse.Namespace) -> int:
    """POST /jobs with a spec file; --wait follows the job to its end."""
    with _client(args) as client:
        job = client.submit(args.spec, seed=args.seed, name=args.name)
        b = job.budget or {}
        if not args.wait:
            if args.json:
                print(json.dumps({"id": job.id, "url": job.url, "status": job.data["status"],
                                  "budget": b}))
            else:
                print(f"job {job.id} {job.data['status']}: {job.url} (budget "
                      f"{b.get('evaluations')} evaluations, {_f(b.get('sim_seconds'), '.0f')} "
                      f"simulated s); follow it with: cmrt watch {job.id}")
            return 0
        if not args.json:
            print(f"job {job.id} submitted: {job.url}", flush=True)
        return _follow(client, job, str(job.data.get("name") or job.id[:8])[:16], args.json)


@_guard
def cmd_watch(args: argparse.Namespace) -> int:
    """Follow a job with a progress bar until it ends; then its result."""
    with _client(args) as client:
        job = client.job(args.job)
        return _follow(client, job, str(job.data["name"])[:16], args.json)


@_guard
def cmd_jobs(args: argparse.Namespace) -> int:
    """GET /jobs as a table (newest first)."""
    with _client(args) as client:
        jobs = client.jobs(status=args.status, family=args.family, limit=args.limit)
        if args.json:
            print(json.dumps([j.data for j in jobs]))
            return 0
        print(f"{'id':<36}  {'status':<9}  {'family':<10}  {'name':<20}  {'best':>9}  "
              f"{'evals':>5}  {'elapsed s':>9}")
        for j in jobs:
            d = j.data
            print(f"{d['id']:<36}  {d['status']:<9}  {d['family'][:10]:<10}  "
                  f"{d['name'][:20]:<20}  {_f(d['best_objective']):>9}  {d['evaluations']:>5}  "
                  f"{_elapsed(d):>9}")
        return 0


def _cmrt_rows(items: list[dict[str, Any]]) -> list[str]:
    rows = [f"{'id':<36}  {'family':<10}  {'task parameters':<28}  {'objective':>9}  "
            f"{'flat':>9}  winner"]
    for e in items:
        params = ", ".join(f"{k}={v:g}" for k, v in sorted(e["task_parameters"].items()))
        rows.append(f"{e['id']:<36}  {e['family'][:10]:<10}  {params[:28]:<28}  "
                    f"{_f(e['objective']):>9}  {_f(e.get('objective_without')):>9}  "
                    f"{e['winner']}{' (falls)' if e['fell'] else ''}")
    return rows


@_guard
def cmd_library(args: argparse.Namespace) -> int:
    """Library queries: list (by family and task parameters), show one, interpolate."""
    with _client(args) as client:
        params = dict(getattr(args, "params", None) or [])
        if args.library_command == "list":
            items = client.cmrts(family=args.family, tolerance=args.tolerance,
                                 limit=args.limit, **params)
            print(json.dumps(items) if args.json else "\n".join(_cmrt_rows(items)))
        elif args.library_command == "show":
            e = client.cmrt(args.cmrt)
            if args.json:
                print(json.dumps(e))
            else:
                print("\n".join(_cmrt_rows([e])))
                print(f"knots {[round(t, 4) for t in e['knot_times']]}")
                print(f"values {[[round(v, 4) for v in row] for row in e['values']]}")
                print(f"source job {e['source']['job_id']}")
        elif args.library_command == "basis":
            b = client.basis(args.family, args.k)
            ve = ", ".join(f"{v:.3f}" for v in b["variance_explained"])
            print(json.dumps(b) if args.json else
                  f"basis {b['id']} of {args.family!r}: k={b['k']}, variance explained [{ve}], "
                  f"{len(b['members'])} members")
        elif args.library_command == "refine":
            job = client.refine(args.family, along=args.along, basis=args.basis,
                                max_evaluations=args.max_evaluations, seed=args.seed,
                                extrapolate=args.extrapolate, **params)
            if not args.wait:
                print(json.dumps({"id": job.id, "url": job.url, "status": job.data["status"],
                                  "start": job.start, "answer": _answer_summary(job.answer)})
                      if args.json else
                      f"refinement job {job.id} {job.data['status']}: {job.url}; "
                      f"{job.start['from']}; follow it with: cmrt watch {job.id}")
                return 0
            if not args.json:
                print(f"refinement job {job.id}: {job.start['from']}", flush=True)
            return _follow(client, job, f"refine {args.family}"[:16], args.json)
        else:
            out = client.interpolate(args.family, along=args.along,
                                     extrapolate=args.extrapolate, verify=args.verify,
                                     **params)
            if args.out:
                Path(args.out).write_text(json.dumps(out, indent=1))
            if args.json:
                print(json.dumps(out))
            else:
                print(_answer_text(out))
        return 0


def _answer_summary(out: dict[str, Any] | None) -> dict[str, Any] | None:
    """An answer without its curve (what a terminal shows)."""
    return None if out is None else {k: v for k, v in out.items() if k != "curve"}


def _answer_text(out: dict[str, Any]) -> str:
    """The library's answer as a few lines: what it is, and what happened when simulated."""
    lines = [f"{out['family']} at {out['key']} = {out['value']:g}: {out['source']} "
             f"({', '.join(out['members'])})"]
    if out.get("note"):
        lines.append(f"note: {out['note']}")
    sw = out.get("switch")
    if sw:
        lines.append(f"neighbours {sw['distance']:.3f} apart (switch above {sw['threshold']:g}): "
                     + ("SWITCH, not averaged" if sw["detected"] else "one strategy"))
    o = out.get("outcome")
    if o:
        lines.append(f"simulated{' (kept)' if o['cached'] else ''}: objective "
                     f"{_f(o.get('objective'))}, fell {o.get('fell')}"
                     + (f" {o['fall_direction']}" if o.get("fall_direction") else "")
                     + f", task success {o.get('task_success')}; verdict {out['verdict']}")
    lines.append(out["message"])
    if out.get("refine"):
        lines.append(f"refine: {out['refine']['command']}")
    return "\n".join(lines)


def _param(text: str) -> tuple[str, float]:
    name, eq, raw = text.partition("=")
    if not eq or not name:
        raise argparse.ArgumentTypeError(f"expected NAME=VALUE (e.g. duration=0.4), got {text!r}")
    try:
        v = float(raw)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{name}: {raw!r} is not a number") from None
    if not math.isfinite(v):
        raise argparse.ArgumentTypeError(f"{name}: must be a finite number, got {raw!r}")
    return name, v


def _seed(text: str) -> int:
    try:
        n = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not an integer") from None
    if not 0 <= n < 2**31:
        raise argparse.ArgumentTypeError(f"must be an integer in [0, 2^31), got {n}")
    return n


def _url_arg(p: argparse.ArgumentParser) -> None:
    p.add_argument("--url", help="the service (default: CMRT_URL, else CMRT_PUBLIC_URL, else "
                                 "http://CMRT_API_HOST:CMRT_API_PORT)")


def add_parsers(sub: Any) -> None:
    """Add submit, jobs, watch and library to the `cmrt` subcommands."""
    from cmrt.client import TERMINAL_STATUSES

    s = sub.add_parser("submit", help="submit a task spec to a running service",
                       description="POST a task spec (YAML or JSON) to the service as a job.")
    s.add_argument("spec")
    _url_arg(s)
    s.add_argument("--seed", type=_seed,
                   help=f"CMA-ES seed (default: {DEFAULT_SEED}, as cmrt optimize)")
    s.add_argument("--name", help="job name (default: the spec's name)")
    s.add_argument("--wait", action="store_true",
                   help="follow the job with a progress bar until it ends, then its result")
    s.add_argument("--json", action="store_true", help="print the answer (or final job) as JSON")
    s.set_defaults(func=cmd_submit)

    j = sub.add_parser("jobs", help="list the service's jobs",
                       description="The service's jobs, newest first.")
    _url_arg(j)
    j.add_argument("--status", choices=("queued", "running", *TERMINAL_STATUSES))
    j.add_argument("--family", help="task family (e.g. bend)")
    j.add_argument("--limit", type=int, default=50, help="at most this many (1..200)")
    j.add_argument("--json", action="store_true")
    j.set_defaults(func=cmd_jobs)

    w = sub.add_parser("watch", help="follow a job with a progress bar",
                       description="Follow a job (generation, evaluations, best, sigma, "
                       "elapsed) until it ends; exit 0 if it converged or stopped at its cap.")
    w.add_argument("job", metavar="JOB", help="job id")
    _url_arg(w)
    w.add_argument("--json", action="store_true", help="print the final job as JSON")
    w.set_defaults(func=cmd_watch)

    lib = sub.add_parser("library", help="query the service's library of CMRTs",
                         description="Library CMRTs by family and task parameters, one entry, "
                         "or an interpolation at task parameter values.")
    lsub = lib.add_subparsers(dest="library_command", required=True)
    ll = lsub.add_parser("list", help="CMRTs by family and task parameters")
    ll.add_argument("params", nargs="*", type=_param, metavar="NAME=VALUE",
                    help="task parameters, e.g. duration=0.4 (needs --family)")
    ll.add_argument("--family")
    ll.add_argument("--tolerance", type=float, help="nearest first within +-tolerance")
    ll.add_argument("--limit", type=int, default=50)
    ls = lsub.add_parser("show", help="one CMRT: knots, values, source job")
    ls.add_argument("cmrt", metavar="CMRT", help="CMRT id")
    li = lsub.add_parser("interpolate", help="the CMRT at task parameter values")
    li.add_argument("params", nargs="+", type=_param, metavar="NAME=VALUE")
    li.add_argument("--family", required=True)
    li.add_argument("--along", help="the interpolated parameter (when several are given)")
    li.add_argument("--extrapolate", action="store_true")
    li.add_argument("--verify", action="store_true",
                    help="simulate the answer once at these values (kept by the library); an "
                         "answer that falls, fails its task or is weak is replaced by the best "
                         "neighbouring member that stands, or said to be no good")
    li.add_argument("--out", metavar="ANSWER.json",
                    help="write the answer; `cmrt simulate SPEC --cmrt ANSWER.json` replays it")
    lb = lsub.add_parser("basis", help="build a PCA basis of a family's library CMRTs")
    lb.add_argument("--family", required=True)
    lb.add_argument("--k", type=int, default=3, help="components (default 3)")
    lr = lsub.add_parser("refine", help="refine the library's answer in the family's basis",
                         description="A job searching the family's PCA basis from the library's "
                         "best answer at the task parameter values, under a small budget; its "
                         "result joins the library as a member.")
    lr.add_argument("params", nargs="+", type=_param, metavar="NAME=VALUE")
    lr.add_argument("--family", required=True)
    lr.add_argument("--along", help="the interpolated parameter (when several are given)")
    lr.add_argument("--extrapolate", action="store_true")
    lr.add_argument("--basis", help="a basis id (default: the family's newest)")
    lr.add_argument("--max-evaluations", type=int, help="the budget (default 150)")
    lr.add_argument("--seed", type=_seed)
    lr.add_argument("--wait", action="store_true", help="follow the job until it ends")
    for p in (ll, ls, li, lb, lr):
        _url_arg(p)
        p.add_argument("--json", action="store_true")
        p.set_defaults(func=cmd_library)
