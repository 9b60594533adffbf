"""A spec file's blocks taken from other files (`task: {file: motion.yaml}`), as every command
line reader sees them (`cmrt.specfile`): inlined relative to the spec's folder, the spec's own
fields laid over the file's; each bad file one message naming the field, exit 2."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest
import yaml

from cmrt import specfile
from cmrt.client import SpecFileError, load_spec_file
from sim.errors import SpecError
from sim.spec import load_spec, parse_spec

CMRT = str(Path(sys.executable).with_name("cmrt"))
MOTION = {"type": "motion", "rate": 10, "joints": ["waist", "shoulder_r"],
          "frames": [[0, 0], [-10, 15], [-30, 40], [-30, 40], [-10, 15], [0, 0]]}
CLIP = {"preparation": 0.5, "duration": 0.5, "decay": 0.5}


def _write(path: Path, data) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(yaml.safe_dump(data))
    return path


def test_a_task_block_from_a_file_is_inlined(tmp_path):
    whole = {"name": "imported", "clip": CLIP, "task": MOTION}
    _write(tmp_path / "clips" / "reach.yaml", whole)  # a whole spec: its task block is taken
    (tmp_path / "clips" / "block.json").write_text(json.dumps(MOTION))  # or the block itself
    spec = _write(tmp_path / "s.yaml", {"name": "s", "clip": CLIP, "task": {
        "type": "motion", "file": "clips/reach.yaml", "speed": 1.25}})
    inline = parse_spec({"name": "s", "clip": CLIP, "task": {**MOTION, "speed": 1.25}})
    assert load_spec(spec) == inline
    assert load_spec_file(spec)["task"] == {**MOTION, "speed": 1.25}  # what `submit` sends
    other = _write(tmp_path / "t.yaml", {"name": "s", "clip": CLIP, "task": {
        "file": str(tmp_path / "clips" / "block.json"), "speed": 1.25}})  # absolute path
    assert load_spec(other) == inline


def test_cmrt_simulate_reads_the_file_as_the_inline_spec(tmp_path):
    _write(tmp_path / "reach.yaml", MOTION)
    by_file = _write(tmp_path / "a.yaml", {"name": "s", "clip": CLIP,
                                           "task": {"file": "reach.yaml"}})
    inline = _write(tmp_path / "b.yaml", {"name": "s", "clip": CLIP, "task": MOTION})
    out = [json.loads(subprocess.run([CMRT, "simulate", str(p), "--json"], check=True,
                                     capture_output=True, text=True).stdout)
           for p in (by_file, inline)]
    assert repr(out[0]["objective"]) == repr(out[1]["objective"]) and not out[0]["fell"]


@pytest.mark.parametrize("content, words", [
    (None, "cannot read the file `task.file` names (no such file)"),
    ("[1, 2]", "holds no mapping"),
    ("frames: [unclosed", "not valid YAML"),
    (yaml.safe_dump({**MOTION, "file": "x.yaml"}), "names another file"),
])
def test_a_bad_referenced_file_names_the_field(tmp_path, content, words):
    if content is not None:
        (tmp_path / "m.yaml").write_text(content)
    spec = _write(tmp_path / "s.yaml", {"name": "s", "clip": CLIP,
                                        "task": {"type": "motion", "file": "m.yaml"}})
    with pytest.raises(SpecError) as err:
        load_spec(spec)
    assert f"{spec}: task.file: " in str(err.value) and words in str(err.value)
    with pytest.raises(SpecFileError, match="task.file"):
        load_spec_file(spec)
    p = subprocess.run([CMRT, "simulate", str(spec)], capture_output=True, text=True)
    assert p.returncode == 2 and "task.file" in p.stderr and "Traceback" not in p.stderr


def test_a_file_name_must_be_a_name_and_a_file_is_bounded(tmp_path, monkeypatch):
    spec = _write(tmp_path / "s.yaml", {"name": "s", "clip": CLIP, "task": {"file": 3}})
    with pytest.raises(SpecError, match="task.file: must be a file name, got 3"):
        load_spec(spec)
    _write(tmp_path / "m.yaml", MOTION)
    spec = _write(tmp_path / "s.yaml", {"name": "s", "clip": CLIP, "task": {"file": "m.yaml"}})
    monkeypatch.setattr(specfile, "MAX_FILE_BYTES", 100)
    with pytest.raises(SpecError, match="task.file: .*larger than 100 bytes"):
        load_spec(spec)
