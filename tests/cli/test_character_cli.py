"""A user's character on the command line: `character: {file: ...}` beside the spec is read
and inlined by every spec reader (cmrt simulate, the client's submit); a missing, unreadable or
invalid file exits 2 naming the field."""

from __future__ import annotations

import json
from pathlib import Path

import yaml

from cli.main import main
from cmrt.client import load_spec_file

EXAMPLES = Path(__file__).resolve().parents[2] / "examples"


def test_simulate_reads_the_character_file_beside_the_spec(capsys, tmp_path):
    assert main(["simulate", str(EXAMPLES / "fast_bend_my_character.yaml"), "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["spec"] == "fast_bend_my_character" and not out["fell"]
    # the same spec with the definition inline gives the same clip
    data = yaml.safe_load((EXAMPLES / "fast_bend_my_character.yaml").read_text())
    data["character"] = {"model": "my_character", "definition": yaml.safe_load(
        (EXAMPLES / "my_character.yaml").read_text())}
    (tmp_path / "inline.yaml").write_text(yaml.safe_dump(data))
    assert main(["simulate", str(tmp_path / "inline.yaml"), "--json"]) == 0
    assert repr(json.loads(capsys.readouterr().out)["objective"]) == repr(out["objective"])


def test_a_bad_character_file_exits_2_naming_the_field(capsys, tmp_path):
    spec = yaml.safe_load((EXAMPLES / "fast_bend_my_character.yaml").read_text())
    (tmp_path / "spec.yaml").write_text(yaml.safe_dump(spec))
    cases = [
        (None, "my_character.yaml: cannot read the file `character.file` names (no such "
               "file)"),
        ("[1, 2", "my_character.yaml: not valid YAML"),
        ("- a list", "my_character.yaml holds no character"),
        ("reference: {height: 1.75, mass: 70}\nroot: pelvis\nsegments: []\n",
         "character.definition: segments: must be a list of at least two segments"),
    ]
    for text, message in cases:
        path = tmp_path / "my_character.yaml"
        path.unlink(missing_ok=True)
        if text is not None:
            path.write_text(text)
        capsys.readouterr()
        assert main(["simulate", str(tmp_path / "spec.yaml")]) == 2, message
        err = capsys.readouterr().err
        assert message in err and "Traceback" not in err, err
        assert "character." in err.partition(": error: ")[2], err  # the field is named
        assert err.count("\n") == 1, err  # one line


def test_the_client_sends_the_definition_never_the_file():
    spec = load_spec_file(EXAMPLES / "fast_bend_my_character.yaml")
    assert "file" not in spec["character"] and "file" not in spec["task"]
    assert spec["character"]["model"] == "my_character"
    assert spec["character"]["definition"] == yaml.safe_load(
        (EXAMPLES / "my_character.yaml").read_text())
