"""Families (optim.family, optim.family_run): spec validation, the plan, the checks'
arithmetic on a family with a known basis, and the embedded runner on synthetic objectives
(a shared pool kept busy, continuation warm starts, resume after a killed run)."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import textwrap
import threading
import time
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from proc_helpers import child_env
from synthetic import LineFamily

from optim.executors import PoolExecutor
from optim.family.checks import family_checks, reconstruction_errors
from optim.family.plan import MEMBER, PROBES, REDUCED, REFERENCE, plan_runs, ready_runs, run_start
from optim.family.spec import SWITCH_DISTANCE, FamilyError, member_spec, parse_family
from optim.family_run import run_family
from optim.result import OptimizationResult

BASE: dict[str, Any] = {
    "name": "fam",
    "family": "fam",
    "task": {"type": "quiet_stance"},
    "clip": {"preparation": 1.0, "duration": 0.4, "decay": 1.0},
    "optimize": {"min_evaluations": 0, "window": 4, "improvement": 0.01,
                 "max_evaluations": 60},
}
VALUES = [1.0, 1.5, 2.0, 2.5, 3.0, 3.5]


def family(**kw: Any) -> Any:
    data = {"spec": BASE, "param": "clip.decay", "values": VALUES,
            "warm": {"sigma0": 0.05, "window": 3, "max_evaluations": 30}, "k": 2, **kw}
    return parse_family(data)


def line_objective(sleep: float = 0.0) -> Any:
    return lambda fs, value: LineFamily(value=value, base=0.1, slope=0.2, sleep=sleep)


# ---- the spec ------------------------------------------------------------------------------------
@pytest.mark.parametrize(("change", "field", "rule"), [
    ({"param": "task.mass"}, "param", "is not in the spec"),
    ({"param": "task.type"}, "param", "must name a number"),
    ({"param": "clip"}, "param", "String should match pattern"),
    ({"values": []}, "values", "at least 1 item"),
    ({"values": [1.0, 1.0, 2.0]}, "values", "must be distinct"),
    ({"values": [1.0, 2.0, 11.0, 3.0, 4.0]}, "values[2]", "clip.decay"),
    ({"leave_out": [1.25]}, "leave_out[0]", "is not one of the values"),
    ({"k": 6}, "k", "need at least"),
    ({"strategy": "chain"}, "strategy", "Input should be"),
    ({"from": "left", "strategy": "continuation"}, "from", "Input should be"),
])
def test_bad_family_names_the_field(change: dict, field: str, rule: str) -> None:
    with pytest.raises(FamilyError) as err:
        family(**change)
    msg = str(err.value)
    assert f"{field}: " in msg and rule in msg, msg


def test_member_specs_set_the_parameter_and_the_warm_rules() -> None:
    fs = family(strategy="continuation")
    main, warm = member_spec(fs, 2.5), member_spec(fs, 2.5, "warm")
    assert main.clip.decay == 2.5 and warm.clip.decay == 2.5
    assert main.name == "fam_decay2.5" and main.family_name == "fam"
    assert main.optimize.max_evaluations == 60 and main.optimize.sigma0 == 0.2
    assert (warm.optimize.sigma0, warm.optimize.window, warm.optimize.max_evaluations) == (
        0.05, 3, 30)


# ---- the plan ------------------------------------------------------------------------------
def test_plan_both_chains_references_and_readiness() -> None:
    fs = family(strategy="continuation", leave_out=[1.0, 2.5])
    runs = plan_runs(fs)
    by = {r.id: r for r in runs}
    assert by["member-up-1.5"].warm_from == "member-up-1"
    assert by["member-down-3"].warm_from == "member-down-3.5"
    assert by["member-down-1"].warm_from == "member-down-1.5"
    # the up chain's cold head is the 1.0 reference; 2.5 needs its own cold run
    assert "reference-1" not in by and by["reference-2.5"].kind == REFERENCE
    first = [r.id for r in ready_runs(runs, set())]
    assert first == ["member-up-1", "member-down-3.5", "reference-2.5"]
    assert [r.id for r in ready_runs(runs, {"member-up-1"}, {"member-down-3.5"})] == [
        "member-up-1.5", "reference-2.5"]
    members = {r.id for r in runs if r.kind == MEMBER}
    assert len(members) == 2 * len(VALUES)
    assert all(set(by[f"reduced-{v}"].needs) == members for v in ("1", "2.5"))
    assert set(by[PROBES].needs) == members
    done = members | {"reference-2.5"}
    assert {r.kind for r in ready_runs(runs, done)} == {REDUCED, PROBES}


def test_plan_middle_and_independent() -> None:
    mid = plan_runs(family(strategy="continuation", **{"from": "middle"}))
    by = {r.id: r for r in mid}
    assert by["member-mid-2"].warm_from is None
    assert by["member-up-2.5"].warm_from == "member-mid-2"
    assert by["member-down-1.5"].warm_from == "member-mid-2"
    assert by["member-down-1"].warm_from == "member-down-1.5"
    ind = plan_runs(family(leave_out=[2.0]))
    assert all(r.warm_from is None for r in ind if r.kind == MEMBER)
    assert not any(r.kind == REFERENCE for r in ind)  # the cold member is the reference
    assert len(ready_runs(ind, set())) == len(VALUES)


# ---- the checks' arithmetic ----------------------------------------------------------------------
def _result(fs: Any, value: float, params: np.ndarray, objective: float,
            bests: list[float], popsize: int = 10, stop: str = "slow_convergence"
            ) -> OptimizationResult:
    history = [{"iteration": i + 1, "evaluations": popsize * (i + 1), "best": b,
                "median": b, "worst": b, "sigma": 0.1, "best_so_far": b}
               for i, b in enumerate(bests)]
    return OptimizationResult.build(member_spec(fs, value), params, objective=objective,
                                     baseline_objective=9.0, evaluations=popsize * len(bests),
                                     iterations=len(bests), stop_rule=stop, history=history,
                                     task_success=True)


def test_checks_on_a_family_with_a_known_basis() -> None:
    fs = family(leave_out=[3.5])
    d = member_spec(fs, 1.0).cmrt_dimension
    a = np.linspace(0.2, 0.6, d)
    u1 = np.ones(d) / np.sqrt(d)
    u2 = np.where(np.arange(d) % 2 == 0, 1.0, -1.0) / np.sqrt(d)
    # every member on the plane a + s u1 + t u2 but 3.5, which is 0.2 (RMS) off it along u3
    u3 = np.zeros(d)
    u3[0], u3[1] = 1.0, 1.0
    u3 -= (u3 @ u1) * u1 + (u3 @ u2) * u2
    u3 /= np.linalg.norm(u3)
    coords = {1.0: (-0.2, 0.1), 1.5: (-0.1, -0.05), 2.0: (0.0, 0.08), 2.5: (0.1, -0.1),
              3.0: (0.15, 0.0), 3.5: (0.2, 0.05)}
    params = {v: a + s * u1 + t * u2 for v, (s, t) in coords.items()}
    params[3.5] = params[3.5] + 0.2 * np.sqrt(d) * u3
    results = {f"member-cold-{v:g}": _result(fs, v, p, 2.0 + v, [3.0 + v, 2.0 + v])
               for v, p in params.items()}
    # the cold run at 3.5 (the member) reached 4.0 at 50 evaluations, its final best;
    # the reduced run reached 4.1 at 20 and stopped at 4.1: relative error +2.5 %
    results["member-cold-3.5"] = _result(fs, 3.5, params[3.5], 4.0,
                                         [9.0, 6.0, 5.0, 4.5, 4.0, 4.0, 4.0, 4.0])
    results["reduced-3.5"] = _result(fs, 3.5, params[3.5], 4.1, [5.0, 4.1, 4.1, 4.1, 4.1])
    checks = family_checks(fs, results, probes={})

    members = {v: results[f"member-cold-{v:g}"] for v in VALUES}
    errs = reconstruction_errors(2, members)
    assert errs[3.5] == pytest.approx(0.2, rel=1e-9)  # the plane of the others: its offset
    # the switch check is the library's: neighbours' parameters more than 0.15 (RMS) apart;
    # on the plane the steps are 0.03-0.07, and 3.5 lies 0.2 off it
    dist = {m.value: m.distance for m in checks.members}
    assert dist[1.0] is None and all(dist[v] < 0.1 for v in VALUES if v not in (1.0, 3.5))
    assert dist[3.5] > 0.2 > fs.switch_threshold == SWITCH_DISTANCE
    assert checks.switches == [3.5]
    row, = checks.rows
    # the basis without 3.5 is the plane: two components explain all of its variance
    assert sum(row.variance_explained) == pytest.approx(1.0, abs=1e-12)
    assert row.basis_members == 5 and row.k == 2
    assert row.reference_objective == 4.0 and row.reference_source == "member"
    assert row.relative_error == pytest.approx(4.1 / 4.0 - 1.0)
    assert (row.cold_converged_at, row.reduced_converged_at) == (50, 20)
    assert row.speedup_converged == pytest.approx(2.5)
    assert (row.cold_to_full, row.reduced_to_full, row.speedup_to_full) == (50, None, None)
    # rule convergence: `window` (4) generations before the stop
    assert (row.cold_rule_converged_at, row.reduced_rule_converged_at) == (40, 10)
    assert row.speedup_rule_converged == pytest.approx(4.0)
    assert checks.medians["worst_relative_error"] == pytest.approx(0.025)


# ---- the runner ----------------------------------------------------------------------------------
class Counting:
    """An executor wrapper counting candidates (thread-safe)."""

    def __init__(self, inner: PoolExecutor) -> None:
        self.inner, self.n, self.lock = inner, 0, threading.Lock()

    @property
    def workers(self) -> int:
        return self.inner.workers

    def map(self, fn: Any, batch: Any, cut_margin: Any = None) -> Any:
        with self.lock:
            self.n += len(batch)
        return self.inner.map(fn, batch)


def test_runner_keeps_the_workers_busy_and_warm_starts_chains(tmp_path: Path, monkeypatch) -> None:
    # popsize 3 on 2 workers: one run alone leaves a worker idle in every other round (at most
    # 3 / 4 busy); the family's concurrent runs fill those rounds from the shared queue
    fs = family(strategy="continuation", leave_out=[1.0, 2.5], values=[1.0, 2.0, 2.5, 3.5],
                spec={**BASE, "optimize": {**BASE["optimize"], "popsize": 3,
                                           "max_evaluations": 36}},
                warm={"sigma0": 0.05, "window": 3, "max_evaluations": 15})
    sleep = 0.02
    monkeypatch.setattr("optim.family_run.member_objective", line_objective(sleep))

    def timed(max_active: int | None, state: str) -> tuple[Any, float]:
        ex = Counting(pool)
        t0 = time.perf_counter()
        out = run_family(fs, ex, tmp_path / state, max_active=max_active)
        wall = time.perf_counter() - t0
        return out, ex.n * sleep / (2 * wall)  # the evaluations' sleep over 2 workers' wall

    with PoolExecutor(2) as pool:
        pool.map(LineFamily(1.0), [np.zeros(8)])  # workers started before the clock
        one, busy_one = timed(1, "one")  # one run at a time, measured beside the family
        out, busy = timed(None, "state")
    runs = plan_runs(fs)
    assert set(out.results) == {r.id for r in runs if r.kind != PROBES}
    assert out.max_concurrent == 3 and one.max_concurrent == 1
    assert one.results.keys() == out.results.keys()
    for rid, res in one.results.items():  # the schedule changes nothing in the results
        assert out.results[rid].params == res.params, rid
    # a machine's load slows both alike; the idle-machine figures are ~0.9 against <= 0.75
    assert busy > 1.15 * busy_one, (busy, busy_one)
    print(f"busy {busy:.2f} (one run at a time: {busy_one:.2f})")
    # each warm member starts from its chain neighbour's optimum (sigma 0.05, warm rules)
    for r in runs:
        if r.kind == MEMBER and r.warm_from is not None:
            st = run_start(fs, r, runs, out.results)
            assert np.array_equal(st.x0, out.results[r.warm_from].params)
            assert st.spec.optimize.sigma0 == 0.05
            assert out.results[r.id].evaluations <= 15 + 3
    checks = family_checks(fs, out.results, out.probes, runs)
    assert len(checks.rows) == 2 and len(checks.probes) == 2


RESUME_SCRIPT = textwrap.dedent("""
    import sys
    from optim.executors import PoolExecutor
    from optim.family.spec import parse_family
    import optim.family_run
    from optim.family_run import run_family
    from synthetic import LineFamily
    import json
    fs = parse_family(json.loads(sys.argv[1]))
    optim.family_run.member_objective = lambda f, v: LineFamily(
        value=v, base=0.1, slope=0.2, sleep=float(sys.argv[3]))
    with PoolExecutor(2) as pool:
        run_family(fs, pool, sys.argv[2], resume=True)
""")


def test_resume_after_a_killed_run_gives_the_same_family(tmp_path: Path, monkeypatch) -> None:
    monkeypatch.setattr("optim.family_run.member_objective", line_objective())
    data = {"spec": BASE, "param": "clip.decay", "values": VALUES, "k": 2,
            "strategy": "continuation", "from": "low", "leave_out": [2.0],
            "warm": {"sigma0": 0.05, "window": 3, "max_evaluations": 30}}
    fs = parse_family(data)
    killed = tmp_path / "killed"
    proc = subprocess.Popen([sys.executable, "-c", RESUME_SCRIPT, json.dumps(data),
                             str(killed), "0.01"], env=child_env(), start_new_session=True)
    try:
        deadline = time.monotonic() + 60
        # kill it mid-run: two members finished, another one's generations checkpointed
        while time.monotonic() < deadline and (len(list(killed.glob("member-*.json"))) < 2
                                               or not list(killed.glob("*.ckpt"))):
            time.sleep(0.02)
        assert proc.poll() is None, "the family finished before it could be killed"
        os.killpg(proc.pid, signal.SIGKILL)
        proc.wait(10)
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
    finished = {p.stem for p in killed.glob("*.json")} - {"family"}
    assert 2 <= len(finished) < len(plan_runs(fs))
    assert list(killed.glob("*.ckpt")), "an active run's checkpoint survives the kill"
    with PoolExecutor(2) as pool:
        resumed = run_family(fs, pool, killed, resume=True)
        fresh = run_family(fs, pool, tmp_path / "fresh")
    assert not set(resumed.started) & finished  # nothing finished was run again
    assert set(resumed.results) == set(fresh.results)
    for rid, res in fresh.results.items():
        other = resumed.results[rid]
        assert other.params == res.params and other.objective == res.objective, rid
        assert other.history == res.history, rid
    assert resumed.probes == fresh.probes
    a = family_checks(fs, resumed.results, resumed.probes).to_dict()
    b = family_checks(fs, fresh.results, fresh.probes).to_dict()
    assert a == b


def test_state_of_another_family_is_refused(tmp_path: Path, monkeypatch) -> None:
    monkeypatch.setattr("optim.family_run.member_objective", line_objective())
    from optim.errors import CheckpointError

    fs = family()
    with PoolExecutor(2) as pool:
        run_family(fs, pool, tmp_path)
        with pytest.raises(CheckpointError, match="earlier family run"):
            run_family(fs, pool, tmp_path)
        with pytest.raises(CheckpointError, match="different family"):
            run_family(family(seed=2), pool, tmp_path, resume=True)


def test_cold_runs_of_another_family_are_reused(tmp_path: Path, monkeypatch) -> None:
    monkeypatch.setattr("optim.family_run.member_objective", line_objective())
    ind = family(leave_out=[2.5])
    chained = family(strategy="continuation", leave_out=[2.5])
    with PoolExecutor(2) as pool:
        first = run_family(ind, pool, tmp_path / "ind")
        fresh = run_family(chained, pool, tmp_path / "fresh")
        lines: list[str] = []
        reused = run_family(chained, pool, tmp_path / "reused",
                            reuse=[tmp_path / "ind"], log=lines.append)
    # the chains' heads (1.0 and 3.5) and the 2.5 reference are the independent members
    copied = {"member-up-1", "member-down-3.5", "reference-2.5"}
    assert copied.isdisjoint(reused.started) and copied <= set(reused.results)
    assert sum(ln.startswith("reuse ") for ln in lines) == 3
    assert reused.results["reference-2.5"].params == first.results["member-cold-2.5"].params
    for rid, res in fresh.results.items():
        assert reused.results[rid].params == res.params, rid
