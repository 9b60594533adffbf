"""`cmrt family run` on real simulations (short bends, one-generation budgets): the output
document, the printed tables, resume, and bad input (exit 2 naming the field, nothing
written)."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
import yaml

from cli.main import main

#: A short bend whose task duration is the family's parameter: cheap to optimise.
BEND = {
    "name": "fam_bend",
    "family": "bend",
    "clip": {"preparation": 0.3, "duration": 0.3, "decay": 0.3},
    "task": {"type": "pose_change",
             "target": {"waist": -40, "shoulder_r": 40, "shoulder_l": 40}},
    "optimize": {"popsize": 4, "max_evaluations": 8, "min_evaluations": 0},
}
OPTIONS: dict[str, list[str]] = {
    "--param": ["clip.duration"], "--values": ["0.2", "0.3", "0.4", "0.5"], "--k": ["2"],
    "--strategy": ["continuation"], "--from": ["both"], "--leave-out": ["0.3"],
    "--workers": ["2"], "--seed": ["3"],
}


def argv(**change: list[str]) -> list[str]:
    """The options above with some replaced (keys: option names without -- and with _)."""
    opts = {**OPTIONS, **{"--" + k.replace("_", "-"): v for k, v in change.items()}}
    return [a for opt, vals in opts.items() for a in (opt, *vals)]


ARGS = argv()


@pytest.fixture
def spec(tmp_path: Path) -> Path:
    p = tmp_path / "bend.yaml"
    p.write_text(yaml.safe_dump(BEND))
    return p


def test_family_run_writes_members_basis_and_checks(spec: Path, tmp_path: Path,
                                                     capsys: pytest.CaptureFixture) -> None:
    out = tmp_path / "fam.json"
    assert main(["family", "run", str(spec), *ARGS, "--out", str(out)]) == 0
    printed = capsys.readouterr().out
    doc = json.loads(out.read_text())
    assert doc["param"] == "clip.duration" and doc["family"] == "bend"
    assert [m["value"] for m in doc["members"]] == [0.2, 0.3, 0.4, 0.5]
    for m in doc["members"]:
        assert {"objective", "fell", "task_success", "evaluations", "params", "curve"} <= set(m)
        assert m["run"].startswith(("member-up-", "member-down-"))
        assert len(m["params"]) == 8 and m["curve"][-1][0] == m["evaluations"]
    assert len(doc["basis"]["variance_explained"]) >= 2 and doc["basis"]["k"] == 2
    row, = doc["checks"]["rows"]
    assert row["value"] == 0.3 and row["basis_members"] == 3
    assert row["relative_error"] == pytest.approx(
        row["reduced_objective"] / row["reference_objective"] - 1.0)
    ids = {r["id"] for r in doc["runs"]}
    assert {"reference-0.3", "reduced-0.3", "member-up-0.2", "member-down-0.5"} <= ids
    assert doc["cost"]["workers"] == 2 and doc["cost"]["cpu_seconds"] > 0
    assert "| clip.duration" not in printed and "| duration |" in printed
    assert "median speed-up" in printed
    # a second command on the same output refuses without --resume, reuses all with it
    assert main(["family", "run", str(spec), *ARGS, "--out", str(out)]) == 2
    assert "pass resume" in capsys.readouterr().err
    assert main(["family", "run", str(spec), *ARGS, "--out", str(out), "--resume",
                 "--json"]) == 0
    again = json.loads(capsys.readouterr().out)
    assert again["cost"]["runs_this_command"] == 0
    assert again["members"] == doc["members"] and again["checks"] == doc["checks"]


@pytest.mark.parametrize(("change", "message"), [
    ({"param": ["task.mass"]}, "param: 'task.mass' is not in the spec"),
    ({"param": ["task.type"]}, "param: 'task.type' must name a number"),
    ({"values": ["0.2", "0.3", "11", "0.5"]}, "values[2]: clip.duration = 11 is refused"),
    ({"leave_out": ["0.25"]}, "leave_out[0]: 0.25 is not one of the values"),
    ({"values": ["0.2", "0.2", "0.3", "0.4"]}, "values: must be distinct"),
    ({"k": ["3"]}, "k: 3 components need at least 5 values"),
    ({"optimize": ["windows=3"]}, "--optimize: 'windows=3' must be KEY=VALUE"),
    ({"optimize": ["window=-1"]}, "spec: optimize.window"),
    ({"warm": ["sigma0=2"]}, "warm.sigma0"),
    ({"workers": ["0"]}, "--workers: must be at least 1"),
])
def test_bad_input_exits_2_naming_the_field_and_writes_nothing(
        spec: Path, tmp_path: Path, capsys: pytest.CaptureFixture,
        change: dict[str, list[str]], message: str) -> None:
    out = tmp_path / "bad.json"
    assert main(["family", "run", str(spec), *argv(**change), "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert message in err, err
    assert not out.exists() and not out.with_suffix(".runs").exists()


def test_empty_values_and_missing_param_are_refused(spec: Path, tmp_path: Path,
                                                    capsys: pytest.CaptureFixture) -> None:
    out = tmp_path / "bad.json"
    for argv in (["--param", "clip.duration", "--values"], ["--values", "0.2", "0.3"]):
        with pytest.raises(SystemExit) as exit_:
            main(["family", "run", str(spec), *argv, "--out", str(out)])
        assert exit_.value.code == 2
        err = capsys.readouterr().err
        assert "--values" in err or "--param" in err
    assert not out.exists() and not out.with_suffix(".runs").exists()
