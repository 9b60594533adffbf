"""A character from the user: a spec's `character.definition` (inline, or read from a file by
the command line), its rules at the boundary, what tasks need of it, and that it simulates and
optimises like a shipped character."""

from __future__ import annotations

import copy
import math
import random
from pathlib import Path
from typing import Any

import pytest
import yaml

from cmrt.canonical import document_hash
from optim.executors import SerialExecutor
from optim.run import optimize
from sim.character import DATA_DIR
from sim.errors import SpecError
from sim.rollout import Rollout
from sim.spec import canonical_spec, load_spec, parse_spec

EXAMPLES = Path(__file__).resolve().parents[2] / "examples"
MINE = yaml.safe_load((EXAMPLES / "my_character.yaml").read_text())
HUMANOID = yaml.safe_load((DATA_DIR / "humanoid.yaml").read_text())
BEND = yaml.safe_load((EXAMPLES / "fast_bend.yaml").read_text())
STANCE = yaml.safe_load((EXAMPLES / "quiet_stance.yaml").read_text())


def _spec(base: dict, character: dict) -> dict:
    return {**copy.deepcopy(base), "character": copy.deepcopy(character)}


def _objective(spec: Any) -> tuple[float, bool]:
    sim = Rollout(spec)
    try:
        ev = sim.run(None)
    finally:
        sim.close()
    return ev.objective, ev.fell


def test_the_examples_without_a_definition_keep_their_canonical_form():
    for path in sorted(EXAMPLES.glob("*.yaml")):
        data = yaml.safe_load(path.read_text())
        if "segments" in data or "character" in data and "file" in data["character"]:
            continue  # the user's character and the spec that reads it
        doc = canonical_spec(load_spec(path)).document
        assert set(doc["character"]) == {"model", "height", "mass"}, path


def test_the_humanoid_as_a_definition_is_the_humanoid():
    """The shipped file given inline simulates exactly as the shipped character."""
    shipped = parse_spec(copy.deepcopy(BEND))
    mine = parse_spec(_spec(BEND, {"definition": HUMANOID, "model": "my_humanoid"}))
    assert (mine.character.height, mine.character.mass) == (1.75, 70.0)  # its reference
    assert repr(_objective(mine)) == repr(_objective(shipped))


def test_inline_and_file_are_one_spec(tmp_path):
    """The file form is the inline form: same canonical document and hash."""
    from_file = canonical_spec(load_spec(EXAMPLES / "fast_bend_my_character.yaml"))
    data = yaml.safe_load((EXAMPLES / "fast_bend_my_character.yaml").read_text())
    data["character"] = {"definition": MINE, "model": "my_character"}
    inline = canonical_spec(parse_spec(data))
    assert from_file.hash == inline.hash and from_file.document == inline.document
    assert from_file.document["character"]["definition"] == MINE
    changed = copy.deepcopy(MINE)
    changed["segments"][1]["mass"] += 0.01
    changed["reference"]["mass"] += 0.01
    data["character"]["definition"] = changed
    assert canonical_spec(parse_spec(data)).hash != inline.hash  # the hash covers it


def test_quiet_stance_stands_on_the_users_character():
    spec = parse_spec(_spec(STANCE, {"definition": MINE, "model": "my_character"}))
    ch = spec.load_character()
    assert ch.total_mass == pytest.approx(74.97) and ch.height == pytest.approx(1.7928)
    objective, fell = _objective(spec)
    assert not fell and objective < 0.05


def test_the_fast_bend_cmrt_lowers_the_objective_on_the_users_character():
    spec = load_spec(EXAMPLES / "fast_bend_my_character.yaml")
    # A short search near the flat spline (sigma0 0.05): three generations of eight.
    short = parse_spec({**canonical_spec(spec).document,
                        "optimize": {"max_evaluations": 24, "min_evaluations": 0,
                                     "popsize": 8, "sigma0": 0.05}})
    res = optimize(short, SerialExecutor(), seed=1)
    assert not res.fell and not res.baseline_fell
    assert res.objective < res.baseline_objective


def _seg(d: dict, name: str) -> tuple[int, dict]:
    return next((i, s) for i, s in enumerate(d["segments"]) if s["name"] == name)


def _set(name: str, key: str, value: Any):
    def mutate(d: dict) -> int:
        i, s = _seg(d, name)
        s[key] = value
        return i
    return mutate


#: (what is wrong, mutation of the definition, the message's field and rule)
BAD = [
    ("1e-9 kg", _set("head", "mass", 1e-9), r"segments\[2\]\.mass: must be at least 0\.1 kg"),
    ("1e6 kg", _set("trunk", "mass", 1e6), r"segments\[1\]\.inertia: must be from"),
    ("NaN", _set("thigh_r", "inertia", float("nan")),
     r"segments\[3\]\.inertia: must be a finite number"),
    ("cycle", _set("thigh_r", "parent", "shank_r"),
     r"segments\[3\]\.parent: 'shank_r' must name a segment listed before"),
    ("two roots", lambda d: _seg(d, "head")[1].pop("parent"),
     r"segments\[2\]\.parent: every segment but the root needs a parent"),
    ("inertia ratio", _set("forearm_l", "inertia", 1e3),
     r"segments\[12\]\.inertia: must be from .* \(a radius of gyration"),
    ("mass ratio", lambda d: (_seg(d, "head")[1].update(mass=0.11, inertia=0.001),
                              d["reference"].update(mass=74.97 - 5.56)),
     r"segments\[2\]\.mass: the heaviest segment \(29\.82 kg\) may be at most 250 times"),
    ("limits reversed", lambda d: _seg(d, "trunk")[1]["joint"].update(limits=[30, -120]),
     r"segments\[1\]\.joint\.limits: must be \[lo, hi\] degrees, lo < hi"),
    ("limits past 180", lambda d: _seg(d, "trunk")[1]["joint"].update(limits=[-200, 30]),
     r"segments\[1\]\.joint\.limits: must lie within \[-180, 180\] degrees"),
    ("heel off the ground", lambda d: _seg(d, "foot_r")[1]["foot"].update(heel=[-0.09, 0.05]),
     r"segments\[5\]\.foot\.heel: must be on the ground"),
    ("a point under the ground", lambda d: _seg(d, "shank_r")[1].update(points=[[0, 0.01, 0.05]]),
     r"segments\[4\]\.points\[0\]: must lie above the ground"),
    ("1000 segments", lambda d: d.update(segments=d["segments"] * 77),
     r"segments: at most 48 segments, got 1001"),
    ("mass sum", lambda d: d["reference"].update(mass=70.0),
     r"reference\.mass: must be the segments' total mass \(74\.97 kg\)"),
    ("unknown field", _set("pelvis", "intertia", 0.05),
     r"segments\[0\]\.intertia: unknown field"),
    ("huge integer", _set("pelvis", "mass", 10**30), r"segments\[0\]\.mass: an integer of 31"),
    ("standing outside its limits", lambda d: d["standing"]["pose"].update(knee_r=5),
     r"standing\.pose\.knee_r: must lie within the joint's limits \[-150, 1\]"),
    ("no feet", lambda d: [s.pop("foot", None) for s in d["segments"]],
     r"segments: at least one segment needs a foot"),
]


@pytest.mark.parametrize(("what", "mutate", "message"), BAD, ids=[b[0] for b in BAD])
def test_each_kind_of_bad_definition_is_named(what, mutate, message):
    d = copy.deepcopy(MINE)
    mutate(d)
    with pytest.raises(SpecError, match=r"^spec: character\.definition: " + message):
        parse_spec(_spec(BEND, {"definition": d}), "spec")


def test_a_task_names_what_it_needs_of_the_character():
    handless = copy.deepcopy(MINE)
    del handless["hands"]
    catch = yaml.safe_load((EXAMPLES / "catch.yaml").read_text())
    with pytest.raises(SpecError, match=(
            r"task\.type: a catch task needs a character with hands .*; "
            r"character\.definition\.hands: character 'one' has none")):
        parse_spec(_spec(catch, {"definition": handless, "model": "one"}), "spec")
    torsoless = copy.deepcopy(MINE)
    del torsoless["torso"]
    push = yaml.safe_load((EXAMPLES / "push.yaml").read_text())
    del push["task"]["body"]  # on the character's torso
    with pytest.raises(SpecError, match=r"task\.type: a push task needs a character with a "
                                        r"torso .*; character\.definition\.torso"):
        parse_spec(_spec(push, {"definition": torsoless}), "spec")
    push["task"]["body"] = "trunk"  # a push on a named body needs no torso
    assert parse_spec(_spec(push, {"definition": torsoless})).task.body == "trunk"
    # a bend needs neither
    parse_spec(_spec(BEND, {"definition": handless}))


def test_names_and_files_at_the_boundary():
    with pytest.raises(SpecError, match=r"character\.model: 'humanoid' is a shipped character"):
        parse_spec(_spec(BEND, {"definition": MINE, "model": "humanoid"}), "spec")
    with pytest.raises(SpecError, match=r"spec: character: file: a character file is read by "
                                        r"the command line"):
        parse_spec(_spec(BEND, {"file": "my_character.yaml"}), "spec")
    spec = parse_spec(_spec(BEND, {"definition": MINE, "height": 1.9}))
    assert spec.character.model == "custom" and spec.character.mass == 74.97
    assert spec.load_character().height == 1.9


def test_the_command_line_reads_the_file_beside_the_spec(tmp_path):
    spec = _spec(BEND, {"file": "chars/mine.yaml"})
    (tmp_path / "spec.yaml").write_text(yaml.safe_dump(spec))
    with pytest.raises(SpecError, match=r"spec\.yaml: character\.file: .*chars/mine\.yaml: "
                                        r"cannot read .*\(no such file\)"):
        load_spec(tmp_path / "spec.yaml")
    (tmp_path / "chars").mkdir()
    (tmp_path / "chars" / "mine.yaml").write_text("segments: [unclosed")
    with pytest.raises(SpecError, match=r"character\.file: .*chars/mine\.yaml: not valid YAML"):
        load_spec(tmp_path / "spec.yaml")
    bad = copy.deepcopy(MINE)
    bad["segments"][0]["mass"] = -1
    (tmp_path / "chars" / "mine.yaml").write_text(yaml.safe_dump(bad))
    with pytest.raises(SpecError, match=r"character\.definition: segments\[0\]\.mass: must be "
                                        r"a positive number"):
        load_spec(tmp_path / "spec.yaml")
    (tmp_path / "chars" / "mine.yaml").write_text(yaml.safe_dump(MINE))
    loaded = load_spec(tmp_path / "spec.yaml")
    assert loaded.character.model == "mine" and loaded.character.definition == MINE


#: Values a fuzzed field may take: every JSON kind, out of range and of the wrong type.
ODD_VALUES = [None, True, "x", "", [], {}, [1], [1, 2, 3], {"a": 1}, -1, 0, 1e300, 10**20,
              -0.5, [{}], [[]], [None, None]]


def _leaves(node: Any, path: tuple = ()) -> list[tuple]:
    if isinstance(node, dict):
        return [path] + [p for k, v in node.items() for p in _leaves(v, (*path, k))]
    if isinstance(node, list):
        return [path] + [p for i, v in enumerate(node) for p in _leaves(v, (*path, i))]
    return [path]


def test_no_definition_raises_anything_but_a_named_spec_error():
    """A seeded fuzz: any field of the definition replaced by any kind of value is either a
    valid character or a SpecError naming `character.definition` (never another exception)."""
    rng = random.Random(38)
    paths = [p for p in _leaves(MINE) if p]
    refused = 0
    for _ in range(600):
        d = copy.deepcopy(MINE)
        path = rng.choice(paths)
        node = d
        for p in path[:-1]:
            node = node[p]
        node[path[-1]] = copy.deepcopy(rng.choice(ODD_VALUES))
        try:
            parse_spec(_spec(BEND, {"definition": d}), "spec")
        except SpecError as err:
            assert str(err).startswith("spec: character"), (path, err)
            refused += 1
    assert refused > 500


def _at_the_edges() -> list[tuple[str, dict]]:
    """Definitions at the bounds' edges: each must simulate to its end (falling is allowed)."""
    out = []

    def variant(what: str, change) -> None:
        d = copy.deepcopy(MINE)
        change(d)
        out.append((what, d))

    def light_feet(d: dict) -> None:  # the lightest allowed, 248 times lighter than the trunk
        for name in ("foot_r", "foot_l"):
            _i, s = _seg(d, name)
            _seg(d, "pelvis")[1]["mass"] += s["mass"] - 0.12
            s.update(mass=0.12, inertia=0.12 * 0.01**2)

    variant("lightest feet", light_feet)
    variant("smallest inertias", lambda d: [s.update(inertia=s["mass"] * 0.01**2)
                                            for s in d["segments"]])
    variant("largest inertias", lambda d: [s.update(inertia=s["mass"] * 0.5**2)
                                           for s in d["segments"]])
    variant("weakest torques", lambda d: d.update(torque_limit=1.0))
    variant("heaviest tracking", lambda d: [s["joint"].update(weight=100.0)
                                            for s in d["segments"][1:]])

    def long_tail(d: dict) -> None:  # 48 segments: a 35-link tail behind the pelvis
        parent = "pelvis"
        for k in range(35):
            x = -0.05 - 0.02 * k
            d["segments"].append({"name": f"tail{k}", "parent": parent, "mass": 0.2,
                                  "inertia": 0.2 * 0.01**2, "com": [x, 1.0],
                                  "joint": {"name": f"tail{k}", "anchor": [x + 0.01, 1.0],
                                            "limits": [-30, 30], "weight": 0.1}})
            parent = f"tail{k}"
        d["reference"]["mass"] = round(sum(s["mass"] for s in d["segments"]), 6)

    variant("48 segments", long_tail)
    return out


@pytest.mark.parametrize(("what", "definition"), _at_the_edges(),
                         ids=[w for w, _ in _at_the_edges()])
def test_definitions_at_the_bounds_simulate_to_their_end(what, definition):
    stance = {**STANCE, "clip": {"preparation": 0.0, "duration": 1.0, "decay": 0.0}}
    spec = parse_spec(_spec(stance, {"definition": definition}))
    objective, _fell = _objective(spec)
    assert math.isfinite(objective), what


def test_the_librarys_identity_of_a_character():
    """A shipped character is told by its dump (as it always was); a definition by its hash."""
    shipped = parse_spec(copy.deepcopy(BEND)).character
    assert shipped.identity() == shipped.model_dump(mode="json")
    mine = parse_spec(_spec(BEND, {"definition": MINE, "model": "mine"})).character
    assert mine.identity() == {"model": "mine", "height": 1.7928, "mass": 74.97,
                               "definition_hash": document_hash(MINE)}
