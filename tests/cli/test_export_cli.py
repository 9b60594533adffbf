"""`cmrt simulate SPEC [--cmrt R] --export OUT.bvh --export OUT.csv [--fps HZ]`: the clip's
motion as the files sim.export writes (the CMRT's clip, not the flat one); misuse is exit 2
with one message and nothing written."""

from __future__ import annotations

import csv

import pytest
import yaml
from bvh_helpers import read

from cli.main import main
from optim.result import load_cmrt
from sim import load_spec
from sim.export import export_text
from sim.rollout import evaluate

SPEC = {"name": "bend_export", "family": "bend",
        "clip": {"preparation": 0.2, "duration": 0.3, "decay": 0.2},
        "task": {"type": "pose_change", "target": {"waist": -30}},
        "optimize": {"popsize": 4, "max_evaluations": 4, "min_evaluations": 0}}


@pytest.fixture
def spec_file(tmp_path):
    path = tmp_path / "bend.yaml"
    path.write_text(yaml.safe_dump(SPEC))
    return path


def test_export_writes_the_cmrts_clip_as_bvh_and_csv(tmp_path, spec_file, capsys):
    result = tmp_path / "r.json"
    assert main(["optimize", str(spec_file), "--workers", "1", "--seed", "2",
                 "--out", str(result)]) == 0
    bvh, table = tmp_path / "m.bvh", tmp_path / "m.csv"
    assert main(["simulate", str(spec_file), "--cmrt", str(result), "--export", str(bvh),
                 "--export", str(table), "--fps", "30"]) == 0
    err = capsys.readouterr().err
    assert f"export: {bvh} (BVH, 30 fps" in err and f"export: {table} (CSV, 30 fps" in err
    spec = load_spec(spec_file)
    ev = evaluate(spec, load_cmrt(result), traces=True)
    ch = spec.load_character()
    assert bvh.read_text() == export_text(ch, ev, "bvh", 30.0)
    assert table.read_text() == export_text(ch, ev, "csv", 30.0)
    mocap = read(bvh.read_text())
    assert mocap.nframes == 21 and mocap.frame_time == pytest.approx(1 / 30)  # 0.7 s clip
    rows = list(csv.reader(table.open()))
    assert len(rows) == 22 and rows[0][4] == ch.hinge_names[0]
    # Without the CMRT the clip is another one; 60 fps by default.
    flat = tmp_path / "flat.bvh"
    assert main(["simulate", str(spec_file), "--zero", "--export", str(flat)]) == 0
    assert flat.read_text() == export_text(ch, evaluate(spec, None, traces=True), "bvh")
    assert flat.read_text() != export_text(ch, ev, "bvh", 60.0)


@pytest.mark.parametrize("args, message", [
    (["--export", "{d}/m.fbx"], "--export {d}/m.fbx: the file's extension names the format, "
                                "one of .bvh, .csv"),
    (["--export", "{d}/m.bvh", "--fps", "0"], "fps: must be a number from 1 to 1000 frames "
                                              "per second, got 0.0"),
    (["--export", "{d}/m.bvh", "--fps", "nan"], "fps: must be a number from 1 to 1000"),
    (["--fps", "30"], "--fps: the frame rate of --export"),
])
def test_misuse_is_exit_2_and_nothing_is_written(tmp_path, spec_file, capsys, args, message):
    argv = [a.format(d=tmp_path) for a in args]
    assert main(["simulate", str(spec_file), *argv]) == 2
    err = capsys.readouterr().err
    assert message.format(d=tmp_path) in err and "Traceback" not in err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["bend.yaml"]
