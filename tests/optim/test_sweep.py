"""Push grids (`optim.sweep`, `cmrt sweep`) on real simulations: a cell is the spec's own clip,
the pool gives what this process gives, the table says survived / fell with the steps, and a
bad grid is refused before anything runs."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from cli.main import main
from optim.executors import PoolExecutor, SerialExecutor
from optim.sweep import PushGrid, cell_document, run_grid, spec_document, survived_ranges, table
from sim.rollout import Rollout
from sim.spec import load_spec, parse_spec

EXAMPLES = Path(__file__).resolve().parents[2] / "examples"
STEP_PUSH = EXAMPLES / "step_push.yaml"


def test_a_cell_of_the_spec_s_own_push_is_the_spec_itself():
    spec = load_spec(STEP_PUSH)
    t = spec.task
    doc = cell_document(spec_document(spec), t.force, spec.clip.duration, t.direction)
    assert parse_spec(doc) == spec
    other = parse_spec(cell_document(spec_document(spec), 125.0, 0.1, "backward"))
    assert other.clip.length == pytest.approx(spec.clip.length)
    assert (other.task.force, other.task.direction, other.clip.duration) == (125.0, "backward",
                                                                             0.1)
    assert other.controller == spec.controller


def test_grid_in_the_pool_is_the_grid_in_this_process_and_the_example_s_clip(capsys):
    """The 300 N x 0.4 s forward cell is examples/step_push.yaml: the same objective as its
    own simulation, survived by stepping; 50 N stands without a step, both ways."""
    assert main(["sweep", str(STEP_PUSH), "--forces", "50", "300", "250", "--durations", "0.4",
                 "--workers", "2", "--json"]) == 0
    cells = json.loads(capsys.readouterr().out)["cells"]
    assert [(c["direction"], c["force"]) for c in cells] == [
        ("forward", 50.0), ("forward", 300.0), ("backward", 50.0), ("backward", 300.0)]
    sim = Rollout(load_spec(STEP_PUSH))
    try:
        own = sim.run(None)
    finally:
        sim.close()
    fwd = cells[1]
    assert repr(fwd["objective"]) == repr(float(own.objective))
    assert fwd["survived"] and fwd["foot_steps"] >= 1
    for c in (cells[0], cells[2]):
        assert c["survived"] and c["foot_steps"] == 0 and c["error"] is None
    grid = PushGrid(load_spec(STEP_PUSH), [50.0, 300.0], [0.4], ["backward"])
    serial = [r.to_dict() for r in run_grid(grid, SerialExecutor())]
    assert serial == cells[2:]
    with PoolExecutor(1) as pool:
        assert [r.to_dict() for r in run_grid(grid, pool)] == serial


def test_table_says_each_cell_and_the_survived_runs(capsys):
    assert main(["sweep", str(STEP_PUSH), "--forces", "50", "50", "25", "--durations", "0.1",
                 "--directions", "backward"]) == 0
    out = capsys.readouterr().out
    assert "force N  backward 0.1 s" in out
    assert "\n50       stands, 0 steps" in out
    assert "backward 0.1 s: survived 1 of 1: 50 N" in out


def test_survived_ranges_are_runs_of_grid_points():
    f = [50.0, 75.0, 100.0, 125.0, 150.0, 175.0]
    assert survived_ranges(f, [True, True, False, True, False, True]) == [
        (50.0, 75.0), (125.0, 125.0), (175.0, 175.0)]
    assert survived_ranges(f, [False] * 6) == []
    assert survived_ranges(f, [True] * 6) == [(50.0, 175.0)]


def test_table_of_a_controller_without_steps_leaves_them_out():
    spec = load_spec(EXAMPLES / "push.yaml")
    grid = PushGrid(spec, [2000.0], [0.2], ["forward"])
    results = run_grid(grid, SerialExecutor())
    assert results[0].foot_steps is None
    text = table(grid, results)
    assert "fell" in text and "step" not in text
    assert "forward 0.2 s: survived 0 of 1: none N" in text


@pytest.mark.parametrize("argv, message", [
    (["examples/punch.yaml", "--forces", "50", "100", "50", "--durations", "0.4"],
     "task.type: a push grid needs a push task, got 'punch'"),
    ([str(STEP_PUSH), "--forces", "0", "100", "50", "--durations", "0.4"],
     "--forces/--durations: 0 N x 0.4 s"),
    ([str(STEP_PUSH), "--forces", "50", "100", "0", "--durations", "0.4"],
     "--forces: FIRST LAST STEP needs STEP > 0"),
    ([str(STEP_PUSH), "--forces", "50", "100", "50", "--durations", "2.45"],
     "--durations: 2.45 s must be > 0 and leave at least 0.1 s of the 3.5 s clip"),
])
def test_bad_grid_exits_2_naming_the_option(argv, message, capsys, monkeypatch):
    monkeypatch.chdir(EXAMPLES.parent)
    assert main(["sweep", *argv]) == 2
    captured = capsys.readouterr()
    assert message in captured.err and captured.out == ""
