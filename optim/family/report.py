"""A finished family's document (`family_report`: the request, every member, every run, the
basis and the checks, as `cmrt family run` writes it and `GET /families/{id}` serves it) and
its markdown tables (`format_tables`)."""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any

from optim.family.checks import family_checks
from optim.family.plan import PROBES, family_members, plan_runs
from optim.family.spec import FamilySpec
from optim.outcome import EvalOutcome
from optim.result import OptimizationResult

FAMILY_FORMAT = "cmrt-family/1"


def curve_of(result: OptimizationResult) -> list[list[float]]:
    """[evaluations, best so far] after each generation."""
    return [[int(h["evaluations"]), float(h["best_so_far"])] for h in result.history]


def family_report(
    fs: FamilySpec,
    results: Mapping[str, OptimizationResult],
    probes: Mapping[float, EvalOutcome] | None = None,
    extra: Mapping[str, Any] | None = None,
) -> dict[str, Any]:
    """The family's JSON document: spec, members, every run, basis and checks."""
    runs = plan_runs(fs)
    chosen = family_members(runs, results)
    checks = family_checks(fs, results, probes, runs)
    members = []
    for v in sorted(chosen):
        rid, r = chosen[v]
        members.append({
            "value": v, "run": rid, "name": r.name, "objective": r.objective, "fell": r.fell,
            "fall_direction": r.fall_direction, "task_success": r.task_success,
            "baseline_objective": r.baseline_objective, "baseline_fell": r.baseline_fell,
            "evaluations": r.evaluations, "stop_rule": r.stop_rule, "params": r.params,
            "knot_times": r.knot_times, "values": r.values,
            "vertical_values": r.vertical_values, "curve": curve_of(r),
        })
    run_rows = []
    for r in runs:
        res = results.get(r.id)
        if res is None or r.kind == PROBES:
            continue
        run_rows.append({"id": r.id, "kind": r.kind, "value": r.value,
                         "warm_from": r.warm_from, "objective": res.objective,
                         "fell": res.fell, "task_success": res.task_success,
                         "evaluations": res.evaluations, "stop_rule": res.stop_rule,
                         "wall_seconds": res.wall_seconds, "basis_id": res.basis_id,
                         "curve": curve_of(res)})
    return {"format": FAMILY_FORMAT, "family": fs.family, "param": fs.param,
            "spec": fs.to_dict(), "members": members, "runs": run_rows,
            "basis": checks.basis, "checks": checks.to_dict(), **dict(extra or {})}


def _f(x: float | None, fmt: str = ".3f") -> str:
    return "-" if x is None or (isinstance(x, float) and math.isnan(x)) else format(x, fmt)


def _switch_pairs(members: list[Mapping[str, Any]]) -> str:
    """The strategy switches as "between A and B", in the members' order."""
    return ", ".join(f"between {a['value']:g} and {b['value']:g}"
                     for a, b in zip(members, members[1:], strict=False) if b["switch"])


def format_tables(report: Mapping[str, Any]) -> str:
    """Markdown tables of a `family_report`: members, interpolation, Table 2 rows."""
    c = report["checks"]
    leaf = report["param"].rsplit(".", 1)[-1]
    out = [f"| {leaf} | run | no CMRT | optimised | fell | task | evaluations | stop rule | "
           "recon. error | from the previous: distance, knot shift (s) |",
           "|---|---|---|---|---|---|---|---|---|---|"]
    for m in c["members"]:
        flag = " **switch**" if m["switch"] else ""
        out.append(f"| {m['value']:g} | {m['run']} | {m['baseline_objective']:.3f} | "
                   f"{m['objective']:.3f} | {m['fell']} | {m['task_success']} | "
                   f"{m['evaluations']} | {m['stop_rule']} | {_f(m['reconstruction_error'])} | "
                   f"{_f(m.get('distance'))}, {_f(m['knot_shift'], '.2f')}{flag} |")
    pairs = _switch_pairs(c["members"])
    ve = c["variance_explained"]
    out.append(f"\nbasis: k = {c['k']}, variance explained per component "
               f"{', '.join(f'{x:.1%}' for x in ve[: c['k']])} (sum "
               f"{sum(ve[: c['k']]):.1%}); strategy switches (neighbours' CMRTs more than "
               f"{c['switch_threshold']:g} apart, the library's check): {pairs or 'none'}")
    out += ["", f"| {leaf} | from | interpolated | fell | task | optimised there | excess |",
            "|---|---|---|---|---|---|---|"]
    for p in c["probes"]:
        out.append(f"| {p['value']:g} | {p['lower']:g}, {p['upper']:g} | {p['objective']:.3f}"
                   f" | {p['fell']} | {p['task_success']} | {p['member_objective']:.3f} | "
                   f"{p['excess']:+.1%} |")
    out += ["", f"| {leaf} | var. expl. (k) | reduced: obj (evals; conv. 1 % / rule) | "
            "reference (source) | cold full: obj (evals; conv. 1 % / rule) | rel. error | "
            "speed-up: 1 % / rule / to full obj |", "|---|---|---|---|---|---|---|"]
    for r in c["rows"]:
        out.append(
            f"| {r['value']:g} | {sum(r['variance_explained']):.1%} | "
            f"{r['reduced_objective']:.3f}{' (fell)' if r['reduced_fell'] else ''} "
            f"({r['reduced_evaluations']}; {r['reduced_converged_at']} / "
            f"{r['reduced_rule_converged_at']}) | {r['reference_objective']:.3f} "
            f"({r['reference_source']}) | {r['cold_objective']:.3f} ({r['cold_evaluations']}; "
            f"{r['cold_converged_at']} / {r['cold_rule_converged_at']}) | "
            f"{r['relative_error']:+.1%} | {_f(r['speedup_converged'], '.2f')}x / "
            f"{_f(r['speedup_rule_converged'], '.2f')}x / {_f(r['speedup_to_full'], '.2f')}x |")
    md = c["medians"]
    if c["rows"]:
        out.append(f"\nmedian speed-up: 1 % {_f(md['speedup_converged'], '.2f')}x, rule "
                   f"{_f(md['speedup_rule_converged'], '.2f')}x, to full objective "
                   f"{_f(md['speedup_to_full'], '.2f')}x; worst relative error "
                   f"{md['worst_relative_error']:+.1%}")
    return "\n".join(out)


__all__ = ["FAMILY_FORMAT", "curve_of", "family_report", "format_tables"]
