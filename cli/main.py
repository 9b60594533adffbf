"""The `cmrt` command line (console script `cmrt = cli.main:main`): simulate, optimize, bench,
sweep, robustness, pca, interpolate, serve, worker; and the client commands submit, jobs, watch,
library (`cli/remote.py`, talking to a running service).

Domain errors become one clear message on stderr and exit status 2; nothing is written then.
"""

from __future__ import annotations

import argparse
import json
import logging
import math
import signal
import sys
import threading
import time
from pathlib import Path
from typing import Any

from cmrt.cmdline import (
    EXIT_BAD_INPUT,
    die,
    positive_int,
    process_settings,
    quiet_plotting_warning,
    terminate_like_interrupt,
)
from cmrt.defaults import DEFAULT_SEED


def _fmt(v: Any) -> str:
    if isinstance(v, float):
        return f"{v:.4f}" if math.isfinite(v) else str(v)
    return str(v)


# ---- simulate ---------------------------------------------------------------------------------
def _sequence_cmrt(spec: Any, base: Path) -> Any:
    """Superpose the CMRTs the motions of a sequence spec name (paper 4.2, Figure 4)."""
    from optim.result import OptimizationResult
    from optim.superpose import superpose

    parts = []
    for m in getattr(spec.task, "motions", None) or []:
        if m.cmrt is None:
            continue
        path = Path(m.cmrt)
        res = OptimizationResult.load(path if path.is_absolute() else base / path)
        # The result's clip started its task at its preparation time; shift it to the motion.
        parts.append((m.start - res.task_spec().clip.task_start, res.spline()))
    return superpose(parts) if parts else None


def cmd_simulate(args: argparse.Namespace) -> int:
    from optim.result import load_cmrt
    from sim import load_spec
    from sim.rollout import Rollout

    spec = load_spec(args.spec)
    cmrt = None
    source = "none"
    if args.cmrt:
        cmrt = load_cmrt(args.cmrt)
        source = args.cmrt
        if abs(cmrt.length - spec.clip.length) > 1e-9:  # a CMRT of another clip: say so
            print(f"note: the CMRT spans {cmrt.length:g} s, the clip {spec.clip.length:g} s",
                  file=sys.stderr)
    elif not args.zero and spec.task_type == "sequence":
        cmrt = _sequence_cmrt(spec, Path(args.spec).parent)
        source = "superposed" if cmrt is not None else "none"
    if args.compare and not args.replay:
        return die("--compare: needs --replay OUT.html")
    if args.compare and cmrt is None:
        return die("--compare: needs a CMRT (--cmrt RESULT.json) to compare with the flat "
                   "spline")
    exports = _export_formats(args)
    record = bool(args.trace or args.replay or exports)
    sim = Rollout(spec)
    t0 = time.perf_counter()
    try:
        ev = sim.run(cmrt, traces=record)
        flat = sim.run(None, traces=True) if args.compare else None
    finally:
        sim.close()
    wall = time.perf_counter() - t0
    if args.trace:
        ev.traces.to_csv(args.trace)
    if args.replay:
        _write_replay(args.replay, spec, ev, cmrt, source, flat)
    if exports:
        _write_exports(exports, spec, ev, args.fps)
    out = {"spec": spec.name, "cmrt": source, **ev.to_dict(), "wall_seconds": wall}
    if args.json:
        print(json.dumps(out))
    else:
        for k in ("spec", "cmrt", "objective", "fell", "fall_time", "fall_reason",
                  "error_norm", "max_abs_error", "sim_seconds", "cpu_seconds"):
            print(f"{k:>14}: {_fmt(out[k])}")
    return 0


def _export_formats(args: argparse.Namespace) -> list[tuple[str, str]]:
    """(path, format) of every --export, the format by the file's extension, checked with
    --fps before anything is simulated (SimError: exit 2, nothing written)."""
    from sim.export import FORMATS, ExportError, check_fps

    out = []
    for path in args.export or []:
        fmt = Path(path).suffix.lower().lstrip(".")
        if fmt not in FORMATS:
            raise ExportError(f"--export {path}: the file's extension names the format, one "
                              f"of {', '.join('.' + f for f in FORMATS)}")
        out.append((path, fmt))
    if args.fps is not None:
        if not out:
            raise ExportError("--fps: the frame rate of --export; give --export OUT.bvh or "
                              "OUT.csv")
        check_fps(args.fps)
    return out


def _write_exports(exports: list[tuple[str, str]], spec: Any, ev: Any, fps: float | None
                   ) -> None:
    """Write the clip as each --export asks (all texts made before any file is written)."""
    from sim.export import DEFAULT_FPS, export_text

    ch = spec.load_character()
    rate = DEFAULT_FPS if fps is None else fps
    texts = [(path, fmt, export_text(ch, ev, fmt, rate)) for path, fmt in exports]
    for path, fmt, text in texts:
        Path(path).write_text(text, encoding="utf-8")
        print(f"export: {path} ({fmt.upper()}, {rate:g} fps, {len(text.encode()) / 1e3:.0f} "
              "kB)", file=sys.stderr)


def _write_replay(path: str, spec: Any, ev: Any, cmrt: Any, source: str, flat: Any) -> None:
    """Write the self-contained replay HTML of the clip (and, with `flat`, the flat-spline
    clip beside it) and say its size on stderr."""
    from service.replay_page import render_replay
    from sim.replay import ReplayClip, build_replay

    label = "with the CMRT" if cmrt is not None else "no anticipation (flat spline)"
    # The result file by name only: a replay file is shared, the local path is not its business.
    about = {"source": source if source in ("none", "superposed") else Path(source).name}
    clips = [ReplayClip(label, ev, cmrt, about)]
    if flat is not None:
        clips.insert(0, ReplayClip("no anticipation (flat spline)", flat, None,
                                   {"source": "none"}))
    html = render_replay(build_replay(spec, clips))
    Path(path).write_text(html, encoding="utf-8")
    print(f"replay: {path} ({len(html.encode()) / 1e6:.3f} MB, {len(clips)} clip"
          f"{'s' if len(clips) > 1 else ''})", file=sys.stderr)


# ---- optimize ---------------------------------------------------------------------------------
def cmd_optimize(args: argparse.Namespace) -> int:
    from optim.executors import PoolExecutor, SerialExecutor
    from optim.pca import Basis
    from optim.result import OptimizationResult
    from optim.run import optimize
    from sim import load_spec

    spec = load_spec(args.spec)
    basis = Basis.load(args.basis) if args.basis else None
    x0 = OptimizationResult.load(args.warm_start).params_array if args.warm_start else None
    out = Path(args.out) if args.out else Path("results") / f"{spec.name}.json"
    ckpt = Path(args.checkpoint) if args.checkpoint else out.with_suffix(".ckpt")
    out.parent.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()

    from cli.progress import ProgressDisplay
    from cmrt.client import Progress

    def progress(st: Any) -> None:
        # A rich bar on a terminal, else one plain line per generation (cli/progress.py).
        # `gen` is the generation's index from 0, as the service and `cmrt watch` number it
        # (st.iteration counts generations from 1).
        show(Progress(job_id="", status="running", generation=st.iteration - 1,
                      evaluations=st.evaluations, max_evaluations=spec.optimize.max_evaluations,
                      best=st.best_so_far, sigma=st.sigma, elapsed=time.perf_counter() - t0))

    executor = SerialExecutor() if args.workers <= 1 else PoolExecutor(args.workers)
    try:
        with ProgressDisplay(sys.stderr, spec.name) as show:
            res = optimize(spec, executor, seed=args.seed, x0=x0, checkpoint=ckpt,
                           resume=args.resume, progress=progress, basis=basis)
    finally:
        executor.close()
    res.save(out)
    summary = {
        "spec": spec.name, "out": str(out), "objective": res.objective, "fell": res.fell,
        "fall_direction": res.fall_direction, "task_success": res.task_success,
        "baseline_objective": res.baseline_objective, "baseline_fell": res.baseline_fell,
        "baseline_fall_direction": res.baseline_fall_direction,
        "baseline_task_success": res.baseline_task_success,
        "evaluations": res.evaluations, "iterations": res.iterations,
        "stop_rule": res.stop_rule, "wall_seconds": res.wall_seconds,
    }
    if res.robust is not None:
        summary["robust"] = res.robust
    if args.json:
        print(json.dumps(summary))
        return 0
    for k, v in summary.items():
        if k != "robust":
            print(f"{k:>18}: {_fmt(v)}")
    for v in (res.robust or {}).get("variants", []):
        at = ", ".join(f"{p} = {x:g}" for p, x in v["values"].items())
        verdict = "stands" if not v["fell"] else f"falls {v['fall_direction']}"
        task = {True: "task done", False: "task failed", None: ""}[v["task_success"]]
        print(f"{'variant':>18}: {at}: {_fmt(v['objective'])} {verdict} {task}".rstrip())
    return 0


# ---- pca / interpolate ------------------------------------------------------------------------
def cmd_pca(args: argparse.Namespace) -> int:
    from optim.pca import build_basis
    from optim.result import OptimizationResult

    results = [OptimizationResult.load(p) for p in args.results]
    basis = build_basis(results, k=args.k)
    basis.save(args.out)
    ve = ", ".join(f"{v:.3f}" for v in basis.variance_explained)
    print(f"basis {basis.id} of {basis.family!r}: k={basis.k}, variance explained [{ve}]"
          f" -> {args.out}")
    return 0


def cmd_interpolate(args: argparse.Namespace) -> int:
    from optim.interpolate import interpolate
    from optim.result import OptimizationResult

    results = [OptimizationResult.load(p) for p in args.results]
    try:  # the library's key (mass) or its spec path (task.mass): one parameter, two names
        key = results[0].task_spec().library_key(args.param)
    except ValueError as err:
        return die(f"--param: {err}")
    if key != args.param:
        print(f"note: --param {args.param} is the library parameter {key!r}", file=sys.stderr)
    interp = interpolate(results, args.at, key=key, extrapolate=args.extrapolate)
    data = interp.to_dict()
    if args.out:
        Path(args.out).write_text(json.dumps(data, indent=2))
    print(json.dumps(data if args.json else {k: v for k, v in data.items() if k != "curve"}))
    return 0


# ---- bench ------------------------------------------------------------------------------------
def cmd_bench(args: argparse.Namespace) -> int:
    from sim import load_spec
    from sim.bench import run_bench, run_task_bench

    specs = [load_spec(p) for p in args.specs]  # parse them all before measuring anything
    reports = [run_bench(seconds=args.seconds, repeat=args.repeat)]
    reports += [run_task_bench(spec, seconds=args.seconds, repeat=args.repeat)
                for spec in specs]
    if args.json:
        print(json.dumps(reports[0] if not specs else reports))
    else:
        for i, report in enumerate(reports):
            if i:
                print()
            for k, v in report.items():
                print(f"{k:>34}: {_fmt(v)}")
    return 0


# ---- sweep ------------------------------------------------------------------------------------
def _grid_values(first: float, last: float, step: float, option: str) -> list[float]:
    """first, first + step, ... up to last (inclusive, within a millionth of a step)."""
    if not all(math.isfinite(v) for v in (first, last, step)) or step <= 0.0 or last < first:
        raise ValueError(f"{option}: FIRST LAST STEP needs STEP > 0 and LAST >= FIRST, got "
                         f"{first:g} {last:g} {step:g}")
    n = int(math.floor((last - first) / step + 1e-6)) + 1
    return [round(first + k * step, 9) for k in range(n)]


def cmd_sweep(args: argparse.Namespace) -> int:
    from optim.executors import PoolExecutor, SerialExecutor
    from optim.sweep import PushGrid, run_grid, table
    from sim import load_spec

    spec = load_spec(args.spec)
    try:
        forces = _grid_values(*args.forces, "--forces")
    except ValueError as err:
        return die(str(err))
    grid = PushGrid(spec, forces, args.durations, args.directions)  # checked before any run
    executor = SerialExecutor() if args.workers <= 1 else PoolExecutor(args.workers)
    t0 = time.perf_counter()
    try:
        results = run_grid(grid, executor)
    finally:
        executor.close()
    wall = time.perf_counter() - t0
    if args.json:
        print(json.dumps({"spec": spec.name, "cells": [r.to_dict() for r in results],
                          "wall_seconds": wall}))
    else:
        print(f"push grid of {spec.name}: {len(results)} clips of {grid.length:g} s, "
              f"push from {spec.clip.preparation:g} s, {wall:.1f} s on {args.workers} "
              f"worker{'s' if args.workers > 1 else ''}")
        print(table(grid, results))
    return 0


# ---- robustness -------------------------------------------------------------------------------
def cmd_robustness(args: argparse.Namespace) -> int:
    from optim.executors import PoolExecutor, SerialExecutor
    from optim.result import OptimizationResult
    from optim.robustness import holds, robustness_spec, run_robustness, table
    from optim.spline import check_params
    from sim import load_spec

    spec = load_spec(args.spec)
    path, lo, hi = args.vary
    try:
        lo, hi = float(lo), float(hi)
    except ValueError:
        return die(f"--vary {path} {lo} {hi}: LO and HI must be numbers")
    canonical = robustness_spec(spec, path, lo, hi, args.steps)  # checked before any run
    result = OptimizationResult.load(args.cmrt)
    params = check_params(spec, result.params_array)
    executor = SerialExecutor() if args.workers <= 1 else PoolExecutor(args.workers)
    t0 = time.perf_counter()
    try:
        rows = run_robustness(canonical, params, executor)
    finally:
        executor.close()
    wall = time.perf_counter() - t0
    values = [r.value for r in rows]
    if args.json:
        print(json.dumps({
            "spec": spec.name, "cmrt": args.cmrt, "path": path, "range": [lo, hi],
            "rows": [r.to_dict() for r in rows],
            "holds": holds([r.cmrt for r in rows], values),
            "flat_holds": holds([r.flat for r in rows], values), "wall_seconds": wall}))
    else:
        print(f"{spec.name} with {args.cmrt} at {len(rows)} values of {path} from {lo:g} to "
              f"{hi:g}: {2 * len(rows)} clips, {wall:.1f} s on {args.workers} worker"
              f"{'s' if args.workers > 1 else ''}")
        print(table(path, rows))
    return 0


# ---- serve / worker ---------------------------------------------------------------------------
def cmd_driver(args: argparse.Namespace) -> int:
    """Job and family drivers in a process of their own (no HTTP): the scanner takes every
    job and family without a live driver, as the API's drivers do, until SIGTERM / SIGINT."""

    from store import open_repository
    from worker.executors import make_generation_executor
    from worker.runner import JobRunner

    settings, level = process_settings(args)
    try:
        repo = open_repository(settings.database_url)
        executor = make_generation_executor(settings)
    except Exception as err:  # noqa: BLE001 - settings or database unusable: one clear line
        return die(f"driver: {err}")
    runner = JobRunner(repo, executor, settings)
    stop = threading.Event()
    for sig in (signal.SIGTERM, signal.SIGINT):
        signal.signal(sig, lambda *_: stop.set())
    runner.start()
    logging.getLogger("cmrt.driver").info(
        "driving jobs and families (%s executor), scanning every %g s", executor.kind,
        settings.scan_interval)
    stop.wait()
    runner.stop(timeout=10)  # running jobs keep their state; the next driver resumes them
    executor.close()
    return 0


def build_parser() -> argparse.ArgumentParser:
    """The `cmrt` command's parser; subcommands in the order `cmrt --help` lists them."""
    p = argparse.ArgumentParser(prog="cmrt", description="Anticipatory balance: CMRT service")
    sub = p.add_subparsers(dest="command", required=True)
    _add_spec_commands(sub)  # simulate, optimize, bench, sweep, robustness
    _add_result_commands(sub)  # pca, interpolate
    _add_service_commands(sub)  # serve, driver, worker

    from cli.characters import add_parsers as add_character_parsers
    from cli.family import add_parsers as add_family_parsers
    from cli.motion import add_parsers as add_motion_parsers
    from cli.remote import add_parsers

    add_parsers(sub)  # submit, jobs, watch, library
    add_family_parsers(sub)  # family run
    add_character_parsers(sub)  # characters list | add | show
    add_motion_parsers(sub)  # motion import
    return p


def _add_spec_commands(sub: Any) -> None:
    """The commands that run a task spec on this machine: simulate, optimize, bench, sweep,
    robustness."""
    s = sub.add_parser("simulate", help="simulate a task spec and print its objective")
    s.add_argument("spec")
    g = s.add_mutually_exclusive_group()
    g.add_argument("--zero", action="store_true", help="no CMRT (the reactive controller alone)")
    g.add_argument("--cmrt", metavar="RESULT.json",
                   help="a CMRT: an optimisation result, an interpolation (`cmrt interpolate "
                        "--out`) or a library answer (`cmrt library interpolate --out`)")
    s.add_argument("--json", action="store_true")
    s.add_argument("--trace", metavar="OUT.csv", help="write per-step traces")
    s.add_argument("--replay", metavar="OUT.html",
                   help="write a self-contained HTML replay of the clip (docs/replay.md)")
    s.add_argument("--compare", action="store_true",
                   help="with --replay and --cmrt: the flat-spline clip beside the CMRT's")
    s.add_argument("--export", action="append", metavar="OUT.bvh|OUT.csv",
                   help="write the clip's motion: BVH (the character's skeleton) or CSV (root, "
                        "joint angles, CM, CP), by the extension; repeatable (docs/export.md)")
    s.add_argument("--fps", type=float, metavar="HZ",
                   help="frames per second of --export (default 60, from 1 to 1000)")
    s.set_defaults(func=cmd_simulate)

    o = sub.add_parser("optimize", help="optimise the CMRT of a task spec with CMA-ES")
    o.add_argument("spec")
    o.add_argument("--workers", type=int, default=2)
    o.add_argument("--seed", type=int, default=DEFAULT_SEED)
    o.add_argument("--out", metavar="RESULT.json")
    o.add_argument("--checkpoint", metavar="PATH", help="default: the --out path with .ckpt")
    o.add_argument("--resume", action="store_true", help="continue from the checkpoint")
    o.add_argument("--basis", metavar="BASIS.json", help="optimise in a PCA-reduced space")
    o.add_argument("--warm-start", metavar="RESULT.json", help="start from an earlier result")
    o.add_argument("--json", action="store_true")
    o.set_defaults(func=cmd_optimize)

    b = sub.add_parser("bench", help="CPU seconds per simulated second, controller vs raw ODE")
    b.add_argument("specs", nargs="*", metavar="SPEC",
                   help="also measure these task specs' worlds (props included) and clips")
    b.add_argument("--seconds", type=float, default=5.0, help="simulated seconds per case")
    b.add_argument("--repeat", type=positive_int, default=1,
                   help="rounds of (raw, controller, replay) per world, the rates over all")
    b.add_argument("--json", action="store_true")
    b.set_defaults(func=cmd_bench)

    w = sub.add_parser("sweep", help="a push task's envelope: survived or fell on a grid of "
                       "forces x durations, forward and backward",
                       description="Simulate a push spec (no CMRT) at every force x duration x "
                       "direction of a grid and print which pushes are survived (with the fall "
                       "time and direction, and the steps a stepping controller took). Each "
                       "clip keeps the spec's length; the push acts over its task window.")
    w.add_argument("spec", help="a spec with a push task (its controller is the one measured)")
    w.add_argument("--forces", type=float, nargs=3, required=True,
                   metavar=("FIRST", "LAST", "STEP"), help="forces in N, LAST included")
    w.add_argument("--durations", type=float, nargs="+", required=True, metavar="S",
                   help="push durations in s")
    w.add_argument("--directions", nargs="+", choices=("forward", "backward"),
                   default=["forward", "backward"])
    w.add_argument("--workers", type=positive_int, default=1,
                   help="process pool size (1: in this process)")
    w.add_argument("--json", action="store_true")
    w.set_defaults(func=cmd_sweep)
    r = sub.add_parser("robustness", help="where a CMRT holds: it and the flat spline at every "
                       "value of one of the spec's numbers over a range",
                       description="Simulate a CMRT (a result file) and the flat spline at "
                       "STEPS evenly spaced values (ends included) of one number of the spec "
                       "(a dotted path, as `family run --param` takes it) and print, per value, "
                       "stands or falls (time, direction), the task's success and the "
                       "objective, then the ranges where each holds.")
    r.add_argument("spec")
    r.add_argument("--cmrt", required=True, metavar="RESULT.json", help="the CMRT to judge")
    r.add_argument("--vary", nargs=3, required=True, metavar=("PATH", "LO", "HI"),
                   help="e.g. task.mass 112 168")
    r.add_argument("--steps", type=positive_int, default=9, help="values, 2-32 (default 9)")
    r.add_argument("--workers", type=positive_int, default=1,
                   help="process pool size (1: in this process)")
    r.add_argument("--json", action="store_true")
    r.set_defaults(func=cmd_robustness)


def _add_result_commands(sub: Any) -> None:
    """The commands that read optimisation results: pca, interpolate."""
    c = sub.add_parser("pca", help="build a PCA basis from a family of results")
    c.add_argument("results", nargs="+")
    c.add_argument("--k", type=int, default=3)
    c.add_argument("--out", required=True)
    c.set_defaults(func=cmd_pca)

    i = sub.add_parser("interpolate", help="interpolate a CMRT at a task parameter value")
    i.add_argument("results", nargs="+")
    i.add_argument("--at", type=float, required=True)
    i.add_argument("--param", default="duration",
                   help="the task parameter: its library name (mass, duration) or its spec "
                        "path (task.mass, clip.duration)")
    i.add_argument("--extrapolate", action="store_true")
    i.add_argument("--out", help="write the interpolated CMRT; `cmrt simulate SPEC --cmrt "
                                 "OUT` and `--replay` take it as it is")
    i.add_argument("--json", action="store_true", help="print the sampled curve too")
    i.set_defaults(func=cmd_interpolate)


def _add_service_commands(sub: Any) -> None:
    """The service's processes: serve (the API), driver, worker."""
    from service import command as serve_command
    from worker import command as worker_command

    v = sub.add_parser("serve", help=serve_command.HELP, description=serve_command.DESCRIPTION)
    serve_command.add_arguments(v)
    v.set_defaults(func=serve_command.run)

    d = sub.add_parser("driver", help="drive jobs and families in a process of their own",
                       description="Run the job and family drivers without the HTTP API: "
                       "every job or family without a live driver is taken and driven (a "
                       "lease admits one driver per job). Run the API with "
                       "CMRT_API_DRIVERS=false to scale or restart it without stopping jobs.")
    d.add_argument("--workers", type=positive_int,
                   help="local pool processes in embedded mode (default CMRT_WORKERS)")
    d.add_argument("--log-level", help="log level (default CMRT_LOG_LEVEL, info)")
    d.set_defaults(func=cmd_driver)

    w = sub.add_parser("worker", help=worker_command.HELP,
                       description=worker_command.DESCRIPTION)
    worker_command.add_arguments(w)
    w.set_defaults(func=worker_command.run)


def _domain_errors() -> tuple[type[Exception], ...]:
    """`ApplicationError`, `SimError` and `OptimError`, of those of their modules the command
    has imported: an error of a module never imported cannot have been raised, and importing
    `sim.errors` here would load the simulator (the `sim` package, numba) into every client
    command."""
    found = []
    for module, name in (("application.errors", "ApplicationError"),
                         ("sim.errors", "SimError"), ("optim.errors", "OptimError")):
        if module in sys.modules:
            found.append(getattr(sys.modules[module], name))
    return tuple(found)


def main(argv: list[str] | None = None) -> int:
    quiet_plotting_warning()
    args = build_parser().parse_args(argv)
    try:
        with terminate_like_interrupt():
            return int(args.func(args) or 0)
    except _domain_errors() as err:  # evaluated once an error is raised: after the command
        # an application error carries its own exit status (75: busy, retry later); the
        # domain's refusals are bad input
        return die(str(err), getattr(err, "exit_code", EXIT_BAD_INPUT))
    except FileNotFoundError as err:
        return die(f"{err.filename}: no such file")
    except KeyboardInterrupt:
        note = {"optimize": "; the checkpoint holds every finished generation (--resume "
                            "continues)",
                "family": "; the .runs folder beside --out holds every finished run and "
                          "the active runs' generations (--resume continues)"}.get(
            getattr(args, "command", None), "")
        print(f"\ncmrt: interrupted{note}", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
