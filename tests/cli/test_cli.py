"""The `cmrt` command line on real simulations: optimise, replay, superpose, bad input."""

from __future__ import annotations

import contextlib
import io
import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
import yaml

from cli.main import main

EXAMPLES = Path(__file__).resolve().parents[2] / "examples"

#: A short bend: cheap enough to optimise for two generations in a test.
BEND = {
    "name": "cli_bend",
    "family": "bend",
    "clip": {"preparation": 0.3, "duration": 0.3, "decay": 0.3},
    "task": {"type": "pose_change",
                 "target": {"waist": -40, "shoulder_r": 40, "shoulder_l": 40}},
    "optimize": {"max_evaluations": 20},
}


@pytest.fixture(scope="module")
def optimised(tmp_path_factory):
    d = tmp_path_factory.mktemp("cli")
    spec = d / "bend.yaml"
    spec.write_text(yaml.safe_dump(BEND))
    out = d / "bend.json"
    err = io.StringIO()
    with contextlib.redirect_stderr(err):
        assert main(["optimize", str(spec), "--workers", "1", "--seed", "2", "--out", str(out),
                     "--json"]) == 0
    return d, spec, out, json.loads(out.read_text()), err.getvalue()


def test_progress_numbers_generations_from_zero_as_the_service(optimised):
    *_, result, stderr = optimised
    gens = [int(ln.split()[1]) for ln in stderr.splitlines() if ln.startswith("gen ")]
    assert gens == list(range(result["iterations"])), stderr


def _simulate(capsys, *argv: str) -> dict:
    capsys.readouterr()
    assert main(["simulate", *argv, "--json"]) == 0
    return json.loads(capsys.readouterr().out)


def test_replay_gives_the_optimised_objective(optimised, capsys):
    d, spec, out, res, _err = optimised
    trace = d / "trace.csv"
    got = _simulate(capsys, str(spec), "--cmrt", str(out), "--trace", str(trace))
    assert got["cmrt"] == str(out)
    assert got["objective"] == res["objective"]  # deterministic: the very same simulation
    zero = _simulate(capsys, str(spec), "--zero")
    assert zero["objective"] == res["baseline_objective"]
    rows = trace.read_text().splitlines()
    assert rows[0].startswith("t,") and len(rows) == 1 + round(0.9 / 0.001)


def test_sequence_superposes_a_stored_cmrt(optimised, capsys):
    """One motion naming the result, at the result's own task time: the superposed CMRT is
    that result's CMRT, so the sequence replays the optimised objective."""
    d, _spec, out, res, _err = optimised
    seq = {
        "name": "cli_seq",
        "clip": BEND["clip"],
        "task": {"type": "sequence", "motions": [
            {"start": 0.3, "duration": 0.3, "target": BEND["task"]["target"],
             "cmrt": out.name}]},
    }
    path = d / "seq.yaml"
    path.write_text(yaml.safe_dump(seq))
    got = _simulate(capsys, str(path))
    assert got["cmrt"] == "superposed"
    assert got["objective"] == pytest.approx(res["objective"], rel=1e-12)
    assert _simulate(capsys, str(path), "--zero")["objective"] == res["baseline_objective"]


def test_bad_spec_names_the_field(tmp_path, capsys):
    bad = dict(BEND, clip={"preparation": -1.0, "duration": 0.3, "decay": 0.3})
    path = tmp_path / "bad.yaml"
    path.write_text(yaml.safe_dump(bad))
    assert main(["simulate", str(path)]) == 2
    err = capsys.readouterr().err
    assert "preparation" in err


def test_missing_result_file(optimised, capsys):
    _d, spec, _out, _res, _err = optimised
    assert main(["simulate", str(spec), "--cmrt", "/nonexistent/r.json"]) == 2
    err = capsys.readouterr().err
    assert "/nonexistent/r.json" in err and "cannot read" in err


def _optimize_cmd(spec, out, *extra: str) -> list[str]:
    return [sys.executable, "-m", "cli.main", "optimize", str(spec), "--workers", "2",
            "--seed", "5", "--out", str(out), "--json", *extra]


def test_kill_9_then_resume_equals_an_uninterrupted_run(tmp_path):
    """`cmrt optimize` killed with SIGKILL after a checkpoint, then `--resume`d, writes the
    result of a run never interrupted (real simulations, a process pool of 2)."""
    spec = tmp_path / "bend.yaml"
    spec.write_text(yaml.safe_dump(dict(BEND, optimize={"max_evaluations": 150})))
    ref_out = tmp_path / "ref.json"
    subprocess.run(_optimize_cmd(spec, ref_out), check=True, capture_output=True, timeout=300)
    out = tmp_path / "killed.json"
    ckpt = out.with_suffix(".ckpt")
    proc = subprocess.Popen(_optimize_cmd(spec, out), stdout=subprocess.DEVNULL,
                            stderr=subprocess.DEVNULL, start_new_session=True)
    deadline = time.monotonic() + 120
    try:
        while not ckpt.exists() and proc.poll() is None and time.monotonic() < deadline:
            time.sleep(0.01)
        assert proc.poll() is None, "finished before its first checkpoint"
        os.killpg(proc.pid, signal.SIGKILL)  # the pool's processes too
    finally:
        proc.wait(timeout=30)
    assert ckpt.exists() and not out.exists()
    subprocess.run(_optimize_cmd(spec, out, "--resume"), check=True, capture_output=True,
                   timeout=300)
    a, b = json.loads(ref_out.read_text()), json.loads(out.read_text())
    for d in (a, b):
        d.pop("wall_seconds")
    assert a == b
    assert a["evaluations"] == 150


def test_sigterm_stops_optimize_cleanly_and_leaves_no_workers(tmp_path):
    """`kill` (SIGTERM) of `cmrt optimize` mid-run: exit status 130 with the interrupted
    message, the checkpoint kept for --resume, no result file, and no pool process left."""
    spec = tmp_path / "bend.yaml"
    spec.write_text(yaml.safe_dump(dict(BEND, optimize={"max_evaluations": 400})))
    out = tmp_path / "term.json"
    ckpt = out.with_suffix(".ckpt")
    proc = subprocess.Popen(_optimize_cmd(spec, out), stdout=subprocess.DEVNULL,
                            stderr=subprocess.PIPE, text=True, start_new_session=True)
    try:
        deadline = time.monotonic() + 120
        while not ckpt.exists() and proc.poll() is None and time.monotonic() < deadline:
            time.sleep(0.01)
        assert proc.poll() is None, "finished before its first checkpoint"
        children = subprocess.run(["pgrep", "-P", str(proc.pid)], capture_output=True,
                                  text=True).stdout.split()
        assert len(children) >= 2  # the pool's workers (and multiprocessing's tracker)
        proc.send_signal(signal.SIGTERM)
        _, err = proc.communicate(timeout=60)
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait(timeout=30)
    assert proc.returncode == 130, err
    assert "interrupted" in err and "--resume" in err
    assert ckpt.exists() and not out.exists()

    def left() -> list[str]:  # multiprocessing's resource tracker ends just after its parent
        ps = subprocess.run(["ps", "-o", "pid=,stat=,args=", "-g", str(proc.pid)],
                            capture_output=True, text=True).stdout.splitlines()
        return [ln for ln in ps if ln.split()[1][0] != "Z"]

    deadline = time.monotonic() + 5.0
    while left() and time.monotonic() < deadline:
        time.sleep(0.05)
    assert left() == [], "processes of the stopped run still alive"


def test_interrupt_of_a_command_without_checkpoint_does_not_promise_one(monkeypatch, capsys):
    import cli.main

    def interrupted(_args):
        raise KeyboardInterrupt

    monkeypatch.setattr(cli.main, "cmd_simulate", interrupted)
    assert main(["simulate", "examples/fast_bend.yaml"]) == 130
    err = capsys.readouterr().err
    assert "interrupted" in err and "checkpoint" not in err


def test_bench_measures_each_task_world_with_its_props(capsys):
    """`cmrt bench SPEC...` adds one report per spec: its world stepped raw (props included)
    against its clip under the controller, both as CPU seconds per simulated second."""
    assert main(["bench", "--seconds", "0.2", "--json", str(EXAMPLES / "catch.yaml")]) == 0
    quiet, catch = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert quiet["simulated_seconds"] == 0.2 and "spec" not in quiet
    assert catch["spec"] == "catch_ball_7" and catch["props"] == 1
    assert catch["controller_simulated_seconds"] > 0.0
    for r in (quiet, catch):
        assert r["raw_ode_cpu_per_sim_second"] > 0.0
        assert r["controller_over_raw_ode"] == pytest.approx(
            r["controller_cpu_per_sim_second"] / r["raw_ode_cpu_per_sim_second"])


@pytest.mark.parametrize("command", ["simulate", "optimize", "bench", "sweep", "pca", "interpolate",
                                     "serve", "worker", "submit", "jobs", "watch", "library",
                                     "family"])
def test_every_subcommand_has_help(command, capsys):
    with pytest.raises(SystemExit) as exit_:
        main([command, "--help"])
    assert exit_.value.code == 0
    assert capsys.readouterr().out.startswith(f"usage: cmrt {command}")


def test_serve_and_worker_take_the_readme_s_options():
    from cli.main import build_parser

    a = build_parser().parse_args(["serve", "--host", "0.0.0.0", "--port", "8000"])
    assert (a.host, a.port) == ("0.0.0.0", 8000)
    assert build_parser().parse_args(["worker", "--concurrency", "2"]).concurrency == 2
    with pytest.raises(SystemExit):
        build_parser().parse_args(["serve", "--port", "0"])
