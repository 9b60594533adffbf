"""`cmrt optimize` on a robust spec and `cmrt robustness`: real simulations, the variants'
outcomes, the table and the ranges where a CMRT holds, and bad input (exit 2, one message,
nothing written)."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
import yaml

from cli.main import main
from optim.objective import SimObjective
from optim.result import OptimizationResult
from optim.robustness import holds
from sim.robust import variant_document
from sim.spec import load_spec, parse_spec

BEND = {"name": "rbend", "family": "bend",
        "clip": {"preparation": 0.2, "duration": 0.2, "decay": 0.2},
        "task": {"type": "pose_change", "target": {"waist": -30}},
        "optimize": {"popsize": 4, "max_evaluations": 8, "min_evaluations": 0,
                     "robust": {"vary": {"task.target.waist": [-40, -20]}, "samples": 2}}}


@pytest.fixture(scope="module")
def optimised(tmp_path_factory):
    """A robust bend optimised on the command line: (spec file, result file, its summary)."""
    tmp = tmp_path_factory.mktemp("robust")
    spec, out = tmp / "rbend.yaml", tmp / "r.json"
    spec.write_text(yaml.safe_dump(BEND))
    import contextlib
    import io

    buf = io.StringIO()
    with contextlib.redirect_stdout(buf):
        assert main(["optimize", str(spec), "--seed", "2", "--out", str(out), "--json"]) == 0
    return spec, out, json.loads(buf.getvalue())


def test_optimize_records_each_variant_and_the_range(optimised) -> None:
    _spec, out, summary = optimised
    res = OptimizationResult.load(out)
    assert summary["robust"] == res.robust
    assert res.robust["vary"] == {"task.target.waist": [-40.0, -20.0]}
    assert [v["values"] for v in res.robust["variants"]] == [
        {"task.target.waist": -40.0}, {"task.target.waist": -20.0}]
    assert res.objective == sum(v["objective"] for v in res.robust["variants"]) / 2


def test_robustness_table_is_each_value_simulated(optimised, capsys) -> None:
    spec, out, _ = optimised
    assert main(["robustness", str(spec), "--cmrt", str(out), "--vary", "task.target.waist",
                 "-50", "-10", "--steps", "3", "--json"]) == 0
    got = json.loads(capsys.readouterr().out)
    assert [r["value"] for r in got["rows"]] == [-50.0, -30.0, -10.0]
    base = load_spec(spec)
    params = OptimizationResult.load(out).params_array
    for row in got["rows"]:
        doc = variant_document(base.model_dump(mode="json"), {"task.target.waist": row["value"]})
        scene = parse_spec(doc)
        assert row["cmrt"]["objective"] == SimObjective(scene)(params).objective
        assert row["flat"]["fell"] == SimObjective(scene)(
            [0.5] * scene.cmrt_dimension).fell
    assert main(["robustness", str(spec), "--cmrt", str(out), "--vary", "task.target.waist",
                 "-50", "-10", "--steps", "3"]) == 0
    text = capsys.readouterr().out
    assert "CMRT holds at task.target.waist" in text and text.count("\n") == 7


def test_holds_gives_contiguous_runs() -> None:
    from optim.outcome import EvalOutcome

    ok, fell = EvalOutcome(1.0), EvalOutcome(9.0, fell=True)
    failed = EvalOutcome(1.0, task_success=False)
    outs = [fell, ok, ok, fell, ok, failed, ok]
    assert holds(outs, [1, 2, 3, 4, 5, 6, 7]) == [(2, 3), (5, 5), (7, 7)]
    assert holds([fell, fell], [1, 2]) == []


@pytest.mark.parametrize(("argv", "message"), [
    (["--vary", "task.nope", "1", "2"], "--vary task.nope 1 2: not a number this spec sets"),
    (["--vary", "task.target.waist", "-10", "-50"],
     "--vary task.target.waist -10 -50: the range must be [lo, hi] with lo < hi"),
    (["--vary", "task.target.waist", "x", "-10"], "LO and HI must be numbers"),
    (["--vary", "optimize.sigma0", "0.1", "0.2"], "the optimize block is not part of the scene"),
    (["--vary", "task.target.waist", "-50", "-10", "--steps", "40"],
     "--steps: must be from 2 to 32 values, got 40"),
])
def test_a_bad_path_or_range_exits_2_with_one_message(optimised, capsys, argv, message):
    spec, out, _ = optimised
    assert main(["robustness", str(spec), "--cmrt", str(out), *argv]) == 2
    err = capsys.readouterr()
    assert message in err.err and err.err.count("\n") == 1 and err.out == ""


def test_optimize_refuses_a_bad_robust_block(tmp_path: Path, capsys) -> None:
    doc = json.loads(json.dumps(BEND))
    doc["optimize"]["robust"]["vary"] = {"task.target.waist": [-40, -20, -10]}
    spec, out = tmp_path / "bad.yaml", tmp_path / "bad.json"
    spec.write_text(yaml.safe_dump(doc))
    assert main(["optimize", str(spec), "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert "optimize.robust.vary.task.target.waist" in err and err.count("\n") == 1
    assert not out.exists()
