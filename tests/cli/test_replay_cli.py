"""`cmrt simulate SPEC [--cmrt R | --zero] --replay OUT.html [--compare]`: one self-contained
file, the flat-spline clip beside the CMRT's with --compare; misuse is exit 2 with a message."""

from __future__ import annotations

import json

import yaml

from cli.main import main

SPEC = {"name": "bend_cli", "family": "bend",
        "clip": {"preparation": 0.2, "duration": 0.3, "decay": 0.2},
        "task": {"type": "pose_change", "target": {"waist": -30}},
        "optimize": {"popsize": 4, "max_evaluations": 4, "min_evaluations": 0}}


def _doc(path):
    html = path.read_text()
    return json.loads(html.split('type="application/json">', 1)[1].split("</script>", 1)[0])


def test_replay_and_compare(tmp_path, capsys):
    spec = tmp_path / "bend.yaml"
    spec.write_text(yaml.safe_dump(SPEC))
    assert main(["optimize", str(spec), "--workers", "1", "--seed", "2",
                 "--out", str(tmp_path / "r.json")]) == 0
    assert main(["simulate", str(spec), "--zero", "--replay", str(tmp_path / "z.html")]) == 0
    (flat,) = _doc(tmp_path / "z.html")["clips"]
    assert flat["label"].startswith("no anticipation") and flat["frames"] == 70
    assert main(["simulate", str(spec), "--cmrt", str(tmp_path / "r.json"), "--json",
                 "--replay", str(tmp_path / "c.html"), "--compare"]) == 0
    out = capsys.readouterr()
    printed = json.loads(out.out.strip().splitlines()[-1])
    doc = _doc(tmp_path / "c.html")
    assert [c["label"] for c in doc["clips"]] == ["no anticipation (flat spline)",
                                                  "with the CMRT"]
    assert doc["clips"][1]["outcome"]["objective"] == round(printed["objective"], 6)
    assert doc["clips"][0]["outcome"]["objective"] == flat["outcome"]["objective"]
    assert "replay: " in out.err and "2 clips" in out.err


def test_misuse_is_exit_2(tmp_path, capsys):
    spec = tmp_path / "bend.yaml"
    spec.write_text(yaml.safe_dump(SPEC))
    assert main(["simulate", str(spec), "--compare"]) == 2
    assert "--compare: needs --replay OUT.html" in capsys.readouterr().err
    assert main(["simulate", str(spec), "--zero", "--compare", "--replay",
                 str(tmp_path / "x.html")]) == 2
    assert "--compare: needs a CMRT" in capsys.readouterr().err
    assert not (tmp_path / "x.html").exists()
