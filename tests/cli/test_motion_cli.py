"""`cmrt motion import` end to end: the shipped example is what its documented command makes;
the humanoid performs it standing (`cmrt simulate`); a short `cmrt optimize` finds a CMRT that
lowers its objective against the flat spline; a bad clip, map or option exits 2 with one line
and writes nothing."""

from __future__ import annotations

import json
import shlex
import subprocess
import sys
from pathlib import Path

import pytest
import yaml

from cli.main import main

ROOT = Path(__file__).resolve().parents[2]
CMRT = str(Path(sys.executable).with_name("cmrt"))
EXAMPLE = ROOT / "examples" / "motion_bend.yaml"


def _cmrt(*args: str, cwd: Path = ROOT) -> subprocess.CompletedProcess:
    return subprocess.run([CMRT, *args], capture_output=True, text=True, cwd=cwd)


def _documented_command() -> list[str]:
    """The example's `Made by:` line, as docs/motion.md and the README give it."""
    first = EXAMPLE.read_text().splitlines()[0]
    assert first.startswith("# Made by: cmrt motion import ")
    return shlex.split(first.removeprefix("# Made by: cmrt "))


def test_the_example_is_what_its_command_makes(tmp_path):
    out = tmp_path / "motion_bend.yaml"
    p = _cmrt(*_documented_command(), "--out", str(out))
    assert p.returncode == 0, p.stderr
    assert out.read_bytes() == EXAMPLE.read_bytes()
    assert p.stdout.splitlines()[0].startswith("clip: cmu_02_06_bend.bvh: frames 0-150")
    assert "clipped: none" in p.stdout and f"wrote {out}" in p.stdout
    docs = (ROOT / "docs" / "motion.md").read_text()
    assert " ".join(_documented_command()) in docs.replace("\\\n", "").replace("  ", " ")


def test_the_humanoid_performs_the_clip_standing_and_a_cmrt_lowers_its_objective(tmp_path):
    p = _cmrt("simulate", str(EXAMPLE), "--json")
    assert p.returncode == 0, p.stderr
    flat = json.loads(p.stdout)
    assert not flat["fell"] and flat["sim_seconds"] == pytest.approx(4.5)
    spec = tmp_path / "short.yaml"
    spec.write_text(yaml.safe_dump({
        "name": "motion_bend_short", "clip": {"preparation": 1, "duration": 2.5, "decay": 1},
        "task": {"file": str(EXAMPLE)},
        "optimize": {"popsize": 6, "max_evaluations": 18, "min_evaluations": 0,
                     "sigma0": 0.05}}))
    p = _cmrt("optimize", str(spec), "--workers", "2", "--seed", "1", "--out",
              str(tmp_path / "r.json"), "--json")
    assert p.returncode == 0, p.stderr
    res = json.loads(p.stdout)
    assert repr(res["baseline_objective"]) == repr(flat["objective"])
    assert not res["fell"] and res["objective"] < res["baseline_objective"]


@pytest.mark.parametrize("args, words", [
    (["tests/data/none.bvh"], "tests/data/none.bvh: cannot read the BVH file (no such file)"),
    (["tests/data/cmu_02_06_bend.bvh"], "none the built-in maps know"),
    (["tests/data/cmu_02_01_walk.bvh", "--map", "tests/data/none.yaml"], "cannot read the map"),
    (["tests/data/cmu_02_01_walk.bvh", "--joints", "wrist"], "--joints: 'wrist'"),
    (["tests/data/cmu_02_01_walk.bvh", "--rate", "0"], "--rate: must be from 1 to 240"),
    (["tests/data/cmu_02_01_walk.bvh", "--rate", "x"], "'x' is not a number"),
    (["tests/data/cmu_02_01_walk.bvh", "--name", "a b"], "name: String should match"),
    (["tests/data/cmu_02_01_walk.bvh", "--character", "nobody"], "nobody"),
])
def test_bad_input_exits_2_and_writes_nothing(tmp_path, monkeypatch, capsys, args, words):
    monkeypatch.chdir(ROOT)
    out = tmp_path / "m.yaml"
    try:
        code = main(["motion", "import", *args, "--out", str(out)])
    except SystemExit as exit_:  # argparse's own errors
        code = exit_.code
    err = capsys.readouterr().err
    assert code == 2, err
    last = err.strip().splitlines()[-1]  # argparse prints its usage before its error
    assert last.startswith("cmrt") and words in last and "Traceback" not in err, err
    assert not out.exists()


def test_a_broken_clip_names_its_line(tmp_path):
    lines = (ROOT / "tests" / "data" / "cmu_02_01_walk.bvh").read_text().splitlines()
    lines[200] = lines[200].replace(" ", " x ", 1)
    bad = tmp_path / "broken.bvh"
    bad.write_text("\n".join(lines) + "\n")
    p = _cmrt("motion", "import", str(bad), "--out", str(tmp_path / "m.yaml"))
    assert p.returncode == 2 and f"{bad}: line 201: frame" in p.stderr, p.stderr


def test_a_user_character_file_takes_the_clip(tmp_path, monkeypatch, capsys):
    """--character FILE: the spec names the file relative to itself (the command line inlines
    it when it reads the spec) and the user's humanoid performs the bend standing."""
    monkeypatch.chdir(ROOT)
    out = tmp_path / "specs" / "bend_mine.yaml"
    args = _documented_command()
    args[args.index("--character") + 1] = "examples/my_character.yaml"
    assert main([*args, "--out", str(out)]) == 0
    block = yaml.safe_load(out.read_text())["character"]
    assert (out.parent / block["file"]).resolve() == ROOT / "examples" / "my_character.yaml"
    capsys.readouterr()
    assert main(["simulate", str(out), "--json"]) == 0
    res = json.loads(capsys.readouterr().out)
    assert not res["fell"]
    assert main([*args[:args.index("--character") + 1], "examples/none.yaml",
                 "--out", str(tmp_path / "x.yaml")]) == 2
    assert "--character: examples/none.yaml: cannot read" in capsys.readouterr().err
