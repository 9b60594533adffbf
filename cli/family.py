"""`cmrt family run`: a family of CMRTs along one task parameter on the embedded default (a
local pool of --workers processes shared by every run), with its PCA basis and checks
(optim.family, optim.family_run; docs/families.md).

    cmrt family run SPEC --param task.mass --values 30 40 50 ... --out F.json
        [--strategy independent|continuation] [--from low|high|both|middle]
        [--warm-sigma S] [--warm KEY=VALUE ...] [--optimize KEY=VALUE ...]
        [--leave-out V ...] [--k 3] [--reduced-start neighbours|centre]
        [--switch-threshold X] [--workers 2] [--seed 1] [--resume] [--reuse DIR ...]
        [--json]

Every finished run is kept in `F.runs/` (the --out path with `.runs`), with a checkpoint per
active run: a killed command continues with --resume and loses nothing finished. Bad input
exits 2 naming the field before anything is written.
"""

from __future__ import annotations

import argparse
import json
import resource
import sys
import time
from pathlib import Path
from typing import Any

import yaml

from cmrt.defaults import DEFAULT_SEED

OPTIMIZE_KEYS = ("threshold", "sigma0", "popsize", "min_evaluations", "max_evaluations",
                 "window", "improvement")
WARM_KEYS = ("sigma0", "min_evaluations", "max_evaluations", "window", "improvement")


class _BadInputError(Exception):
    """A command-line value is refused (message names the option)."""


def _pairs(items: list[str] | None, option: str, keys: tuple[str, ...]) -> dict[str, Any]:
    """KEY=VALUE pairs (values read as YAML scalars; `none` clears a setting)."""
    out: dict[str, Any] = {}
    for item in items or []:
        key, sep, raw = item.partition("=")
        if not sep or key not in keys:
            raise _BadInputError(f"{option}: {item!r} must be KEY=VALUE with KEY one of "
                            f"{', '.join(keys)}")
        value = yaml.safe_load(raw) if raw.strip().lower() not in ("none", "null") else None
        out[key] = value
    return out


def family_request(args: argparse.Namespace) -> dict[str, Any]:
    """The family mapping (optim.family.spec.parse_family's input) from the command line."""
    from cmrt.specfile import SpecReadError, read_spec_file
    from sim.errors import SpecError

    try:
        spec = read_spec_file(args.spec)
    except SpecReadError as err:
        raise SpecError(str(err)) from None
    overrides = _pairs(args.optimize, "--optimize", OPTIMIZE_KEYS)
    if overrides:
        block = dict(spec.get("optimize") or {})
        for key, value in overrides.items():
            if value is None:
                block.pop(key, None)
            else:
                block[key] = value
        spec["optimize"] = block
    warm = _pairs(args.warm, "--warm", WARM_KEYS)
    if args.warm_sigma is not None:
        warm["sigma0"] = args.warm_sigma
    data: dict[str, Any] = {
        "spec": spec, "param": args.param, "values": args.values,
        "strategy": args.strategy, "from": args.start_from, "warm": warm,
        "leave_out": args.leave_out or [], "k": args.k, "seed": args.seed,
        "reduced_start": args.reduced_start,
    }
    if args.switch_threshold is not None:
        data["switch_threshold"] = args.switch_threshold
    return data


def _cpu_seconds() -> float:
    """CPU seconds of this process and of its finished children (the pool's workers)."""
    own = resource.getrusage(resource.RUSAGE_SELF)
    kids = resource.getrusage(resource.RUSAGE_CHILDREN)
    return own.ru_utime + own.ru_stime + kids.ru_utime + kids.ru_stime


def cmd_family_run(args: argparse.Namespace) -> int:
    from cmrt.cmdline import die
    from optim._io import atomic_write_text
    from optim.executors import PoolExecutor
    from optim.family.report import format_tables
    from optim.family.spec import parse_family
    from optim.family_run import run_family

    try:
        request = family_request(args)
    except _BadInputError as err:
        return die(str(err))
    if args.workers < 1:
        return die("--workers: must be at least 1")
    fs = parse_family(request)  # FamilyError (exit 2) before anything is written
    out = Path(args.out)
    state_dir = out.with_suffix(".runs")
    t0, cpu0 = time.perf_counter(), _cpu_seconds()

    def log(msg: str) -> None:
        print(f"[{time.perf_counter() - t0:6.0f} s] {msg}", file=sys.stderr, flush=True)

    with PoolExecutor(args.workers) as pool:
        outcome = run_family(fs, pool, state_dir, resume=args.resume, log=log,
                             reuse=[Path(p) for p in args.reuse or []])
    wall, cpu = time.perf_counter() - t0, _cpu_seconds() - cpu0
    evaluations = sum(r.evaluations + 2 for r in outcome.results.values()) + len(outcome.probes)
    extra = {"cost": {
        "workers": args.workers, "wall_seconds": wall, "cpu_seconds": cpu,
        "runs_this_command": len(outcome.started),
        "evaluations_total": evaluations,
        "note": "wall and CPU seconds of this command only (a resumed family's earlier "
                "commands not included); CPU: this process and its pool's workers",
    }}
    report = {**outcome.report, **extra}
    out.parent.mkdir(parents=True, exist_ok=True)
    atomic_write_text(out, json.dumps(report, indent=1, allow_nan=False) + "\n")
    if args.json:
        print(json.dumps(report))
    else:
        print(format_tables(report))
        print(f"\n{len(outcome.started)} runs in this command, {wall:.0f} s wall, {cpu:.0f} s "
              f"CPU on {args.workers} workers; {evaluations} evaluations in the family; "
              f"written {out}")
    return 0


def _family_lines(d: dict[str, Any]) -> list[str]:
    """A family's state in a few lines; once done, its tables
    (optim.family.report.format_tables)."""
    from optim.family.report import format_tables

    p = d.get("progress") or {}
    lines = [f"family {d['id']} {d['status']}: {d['family']} along {d['param']}, "
             f"{len(d.get('values') or [])} values; runs {p.get('done', '?')} of "
             f"{p.get('runs', '?')} done, {p.get('running', 0)} running"]
    if d.get("error"):
        lines.append(f"error: {d['error']}")
    if d.get("checks"):
        lines.append(format_tables({"checks": d["checks"], "param": d["param"]}))
    return lines


def _follow_family(fam: Any, as_json: bool) -> int:
    from cli.remote import EXIT_JOB_FAILED

    last = [None]

    def show(d: dict[str, Any]) -> None:
        p = d.get("progress") or {}
        line = (f"{d['status']}: {p.get('done')} of {p.get('runs')} runs done, "
                f"{p.get('running')} running, {p.get('queued')} queued")
        if line != last[0]:
            print(line, file=sys.stderr if as_json else sys.stdout, flush=True)
            last[0] = line

    final = fam.wait(on_progress=show, poll=1.0)
    if as_json:
        print(json.dumps(final))
    else:
        print("\n".join(_family_lines(final)))
    return 0 if final["status"] == "done" else EXIT_JOB_FAILED


def _guarded(fn: Any) -> Any:
    from cli.remote import _guard

    return _guard(fn)


def cmd_family_submit(args: argparse.Namespace) -> int:
    from cli.remote import _client
    from cmrt.cmdline import die

    try:
        request = family_request(args)
    except _BadInputError as err:
        return die(str(err))

    @_guarded
    def go(args: argparse.Namespace) -> int:
        with _client(args) as client:
            fam = client.submit_family(request)
            b = fam.budget or {}
            if not args.wait:
                if args.json:
                    print(json.dumps({"id": fam.id, "url": fam.url, "status": "running",
                                      "budget": b}))
                else:
                    print(f"family {fam.id} running: {fam.url} (budget {b.get('evaluations')} "
                          f"evaluations, {b.get('sim_seconds', 0):.0f} simulated s); follow "
                          f"it with: cmrt family watch {fam.id}")
                return 0
            if not args.json:
                print(f"family {fam.id} submitted: {fam.url}", flush=True)
            return _follow_family(fam, args.json)

    return go(args)


def cmd_family_show(args: argparse.Namespace) -> int:
    from cli.remote import _client

    @_guarded
    def go(args: argparse.Namespace) -> int:
        with _client(args) as client:
            d = client.family(args.family).data
            print(json.dumps(d) if args.json else "\n".join(_family_lines(d)))
            return 0

    return go(args)


def cmd_family_watch(args: argparse.Namespace) -> int:
    from cli.remote import _client

    @_guarded
    def go(args: argparse.Namespace) -> int:
        with _client(args) as client:
            return _follow_family(client.family(args.family), args.json)

    return go(args)


def _request_options(r: argparse.ArgumentParser) -> None:
    """The family request's options, shared by `run` and `submit`."""
    r.add_argument("spec", help="the base task spec (YAML or JSON)")
    r.add_argument("--param", required=True, help="path of a number in the spec, e.g. task.mass")
    r.add_argument("--values", type=float, nargs="+", required=True)
    r.add_argument("--strategy", choices=["independent", "continuation"],
                   default="independent")
    r.add_argument("--from", dest="start_from", choices=["low", "high", "both", "middle"],
                   default="both", help="continuation: where the chains start")
    r.add_argument("--warm-sigma", type=float, metavar="S",
                   help="continuation: CMA-ES sigma0 of the warm-started members (0.05)")
    r.add_argument("--warm", nargs="+", metavar="KEY=VALUE",
                   help=f"continuation members' rules ({', '.join(WARM_KEYS)})")
    r.add_argument("--optimize", nargs="+", metavar="KEY=VALUE",
                   help="override the spec's optimize block for the main rules "
                        f"({', '.join(OPTIMIZE_KEYS)}; KEY=none clears it)")
    r.add_argument("--leave-out", type=float, nargs="*", metavar="V")
    r.add_argument("--k", type=int, default=3)
    r.add_argument("--reduced-start", choices=["neighbours", "centre"], default="neighbours")
    r.add_argument("--switch-threshold", type=float, metavar="X")
    r.add_argument("--seed", type=int, default=DEFAULT_SEED)
    r.add_argument("--json", action="store_true", help="print the whole report as JSON")


def add_parsers(sub: Any) -> None:
    """`cmrt family run` (embedded) and `submit`, `show`, `watch` (against a service)."""
    from cli.remote import _url_arg

    f = sub.add_parser("family", help="families of CMRTs along a task parameter")
    fsub = f.add_subparsers(dest="family_command", required=True)
    s = fsub.add_parser(
        "submit", help="grow a family on a running service (POST /families)",
        description="The same request as `cmrt family run`, run by the service as jobs.")
    _request_options(s)
    _url_arg(s)
    s.add_argument("--wait", action="store_true", help="follow it until it ends, then its checks")
    s.set_defaults(func=cmd_family_submit)
    for name, helptext, fn in (("show", "a family's state, members and checks", cmd_family_show),
                               ("watch", "follow a family until it ends", cmd_family_watch)):
        p = fsub.add_parser(name, help=helptext)
        p.add_argument("family", metavar="FAMILY", help="family id")
        _url_arg(p)
        p.add_argument("--json", action="store_true")
        p.set_defaults(func=fn)
    r = fsub.add_parser(
        "run", help="optimise a family on the embedded default, with its basis and checks",
        description="Optimise the CMRTs of SPEC with PARAM set to each of VALUES, then its "
        "PCA basis and checks: per leave-out value the interpolated CMRT and a reduced-space "
        "run in the basis of the other members (Table 2). docs/families.md.")
    _request_options(r)
    r.add_argument("--workers", type=int, default=2)
    r.add_argument("--out", required=True, metavar="F.json")
    r.add_argument("--resume", action="store_true",
                   help="continue the family kept in F.runs/ (the --out path with .runs)")
    r.add_argument("--reuse", nargs="+", metavar="DIR",
                   help="other families' .runs folders: their finished cold runs with this "
                        "family's exact spec and seed are copied instead of run again")
    r.set_defaults(func=cmd_family_run)
