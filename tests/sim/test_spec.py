"""Task specs: the examples load; bad specs raise SpecError naming the field and the rule."""

from __future__ import annotations

from pathlib import Path

import pytest
import yaml

from sim.errors import SpecError
from sim.spec import TaskSpec, load_spec, parse_spec

EXAMPLES_DIR = Path(__file__).resolve().parents[2] / "examples"
#: The example specs (examples/ also holds a user's character file, which is no spec).
EXAMPLES = sorted(p for p in EXAMPLES_DIR.glob("*.yaml")
                  if "segments" not in yaml.safe_load(p.read_text()))


def _load(name: str) -> dict:
    return yaml.safe_load((EXAMPLES_DIR / f"{name}.yaml").read_text())


def test_examples_present():
    names = {p.stem for p in EXAMPLES}
    assert {"quiet_stance", "push", "slow_bend", "fast_bend"} <= names


@pytest.mark.parametrize("path", EXAMPLES, ids=lambda p: p.stem)
def test_example_loads(path):
    spec = load_spec(path)
    assert isinstance(spec, TaskSpec)
    assert spec.clip.length > 0
    assert spec.cmrt_dimension == (3 if spec.cmrt.vertical else 2) * spec.cmrt.knots


def test_example_contents():
    push = load_spec(EXAMPLES_DIR / "push.yaml")
    assert push.task_type == "push" and push.task.force == 100.0
    assert push.task.window(push.clip) == (1.0, 0.2)  # defaults to the task window
    assert push.task_parameters() == {"duration": 0.2, "force": 100.0}
    fast = load_spec(EXAMPLES_DIR / "fast_bend.yaml")
    slow = load_spec(EXAMPLES_DIR / "slow_bend.yaml")
    assert fast.task.target == slow.task.target
    assert fast.clip.duration < slow.clip.duration
    # A schedule without start/end covers the task window.
    for path in EXAMPLES:
        spec = load_spec(path)
        for entry in spec.schedule:
            if entry.start is None and entry.end is None:
                assert spec.schedule_window(entry) == (spec.clip.task_start, spec.clip.task_end)


def _unknown_joint(d):
    d["task"]["target"]["wrist"] = 10.0
    return "slow_bend", "task.target", "unknown joint 'wrist'"


def _joint_out_of_range(d):
    d["task"]["target"]["waist"] = -200.0
    return "slow_bend", "task.target.waist", "must be from -180 to 180 degrees, got -200.0"


def _negative_duration(d):
    d["clip"]["duration"] = -0.5
    return "slow_bend", "clip.duration", "must be from 0.001 to 10 s, got -0.5"


def _duration_under_one_step(d):
    d["clip"]["duration"] = 5e-324
    return "slow_bend", "clip.duration", "must be from 0.001 to 10 s, got 5e-324"


def _negative_decay(d):
    d["clip"]["decay"] = -1.0
    return "slow_bend", "clip.decay", "must be from 0 to 10 s, got -1.0"


def _clip_too_long(d):
    d["clip"] = {"preparation": 10.0, "duration": 10.0, "decay": 10.0}
    return "slow_bend", "clip", "exceeds 20 s"


def _unknown_top_field(d):
    d["colour"] = "red"
    return "slow_bend", "colour", "Extra inputs are not permitted"


def _unknown_nested_field(d):
    d["clip"]["prep"] = 1.0
    return "slow_bend", "clip.prep", "Extra inputs are not permitted"


def _missing_push_force(d):
    del d["task"]["force"]
    return "push", "task.force", "Field required"


def _push_field_on_bend(d):
    d["task"]["force"] = 50.0
    return "slow_bend", "task.force", "Extra inputs are not permitted"


def _push_past_clip_end(d):
    d["task"]["start"] = 2.9  # + 0.2 s default duration > 3.0 s clip
    return "push", "task", "start + duration exceeds the clip length"


def _push_duration_past_end(d):
    d["task"]["start"] = 1.0
    d["task"]["duration"] = 2.5
    return "push", "task", "start + duration exceeds the clip length"


def _negative_force(d):
    d["task"]["force"] = -100.0
    return "push", "task.force", "must be from 1 to 5000 N, got -100.0"


def _push_unknown_body(d):
    d["task"]["body"] = "tail"
    return "push", "task.body", "unknown body 'tail'"


def _task_without_type(d):
    d["task"] = {"force": 10.0}
    return "push", "task", "needs a `type`"


def _string_duration(d):
    d["clip"]["duration"] = "0.2"
    return "push", "clip.duration", "valid number"


def _boolean_duration(d):
    d["clip"]["duration"] = True
    return "push", "clip.duration", "valid number"


def _infinite_threshold(d):
    d["optimize"]["threshold"] = float("inf")  # what JSON's 1e999 parses to
    return "push", "optimize.threshold", "finite number"


def _nan_force(d):
    d["task"]["force"] = float("nan")
    return "push", "task.force", "finite number"


def _nul_in_family(d):
    d["family"] = "pu\x00sh"
    return "push", "family", "control character"


def _float_knots(d):
    d["cmrt"] = {"knots": 4.0}
    return "push", "cmrt.knots", "valid integer"


def _cop_box_too_wide(d):
    d["controller"] = {"type": "momentum", "cop_box": 0.5}
    return "push", "controller.cop_box", "below half the support length"


def _scheduled_cop_box_too_wide(d):
    d["schedule"] = [{"set": {"cop_box": 0.2}}]
    return "slow_bend", "schedule.0.set.cop_box", "below half the support length"


def _unknown_character(d):
    d["character"] = {"model": "robot"}
    return "push", "character.model", "unknown character 'robot'"


def _unknown_gain_in_schedule(d):
    d["schedule"] = [{"scale": {"k_t": 2.0, "k_x": 2.0}, "ramp": 0.05}]
    return "slow_bend", "schedule.0.scale", "unknown gain 'k_x'"


def _unknown_gain_in_controller(d):
    d["controller"] = {"type": "momentum", "kl": 20.0}
    return "slow_bend", "controller", "unknown gain 'kl'"


def _schedule_without_changes(d):
    d["schedule"] = [{"ramp": 0.05}]
    return "slow_bend", "schedule.0", "needs `scale` or `set`"


def _schedule_scale_and_set_same_gain(d):
    d["schedule"] = [{"scale": {"b_p": 2.0}, "set": {"b_p": 1.0}}]
    return "slow_bend", "schedule.0", "b_p: in both `scale` and `set`"


def _schedule_set_negative(d):
    d["schedule"] = [{"set": {"b_p": -1.0}}]
    return "slow_bend", "schedule.0.set.b_p", "must be from 0 to 10000 in the gain's unit"


def _schedule_end_before_start(d):
    d["schedule"] = [{"scale": {"k_t": 2.0}, "start": 1.3, "end": 1.2}]
    return "slow_bend", "schedule.0", "end must be after start"


def _bad_name(d):
    d["name"] = "has space"
    return "slow_bend", "name", "should match pattern"


def _unknown_task(d):
    d["task"] = {"type": "walk"}
    return "slow_bend", "task", "unknown task type 'walk'"


BAD_SPECS = [
    _unknown_joint, _joint_out_of_range, _negative_duration, _duration_under_one_step,
    _negative_decay, _clip_too_long,
    _unknown_top_field, _unknown_nested_field, _missing_push_force, _push_field_on_bend,
    _push_past_clip_end, _push_duration_past_end, _negative_force, _push_unknown_body,
    _task_without_type, _string_duration, _boolean_duration, _infinite_threshold, _nan_force,
    _nul_in_family, _float_knots, _cop_box_too_wide, _scheduled_cop_box_too_wide,
    _unknown_character, _unknown_gain_in_schedule,
    _unknown_gain_in_controller, _schedule_end_before_start, _bad_name, _unknown_task,
    _schedule_without_changes, _schedule_scale_and_set_same_gain, _schedule_set_negative,
]


@pytest.mark.parametrize("mutate", BAD_SPECS, ids=lambda f: f.__name__.strip("_"))
def test_bad_spec_names_field_and_rule(mutate):
    # Each mutator edits the dict it is given and returns (the example it expects, the field,
    # the rule); a first dry run on a throwaway dict of every example finds which one.
    for name in ("slow_bend", "push"):
        data = _load(name)
        try:
            example, field, rule = mutate(data)
        except (KeyError, IndexError):
            continue
        if example == name:
            break
    else:  # pragma: no cover
        pytest.fail("the mutation applies to no example")
    with pytest.raises(SpecError) as info:
        parse_spec(data, source="bad.yaml")
    msg = str(info.value)
    assert msg.startswith("bad.yaml: "), msg
    assert field in msg, msg
    assert rule in msg, msg
    # SpecError is a ValueError for callers that only know the standard library.
    assert isinstance(info.value, ValueError)
    # The unmodified example is valid: the error is the mutation's.
    parse_spec(_load(example))


def test_non_mapping_and_unreadable(tmp_path):
    with pytest.raises(SpecError, match="a spec must be a mapping, got list"):
        parse_spec([1, 2])
    with pytest.raises(SpecError, match="cannot read spec"):
        load_spec(tmp_path / "missing.yaml")
    bad = tmp_path / "bad.yaml"
    bad.write_text("name: [unclosed\n")
    with pytest.raises(SpecError, match="not valid YAML"):
        load_spec(bad)
    js = tmp_path / "s.json"
    js.write_text('{"name": "q", "task": {"type": "quiet_stance"}, "clip": {"duration": 1.0}}')
    assert load_spec(js).clip.length == 3.0  # default preparation 1 s and decay 1 s


def test_a_task_named_alone_is_refused_saying_what_to_send():
    """The form before the registry (`task: push` + a `push:` block) is no longer read: the
    error names the field and the form to send."""
    old = {k: v for k, v in _load("push").items() if k != "task"}
    old.update({"task": "push", "push": {"force": 100.0, "direction": "forward",
                                         "body": "trunk"}})
    with pytest.raises(SpecError, match=r"task: must be a mapping with its type, e\.g\. "
                                        r"\{type: push, \.\.\.\}"):
        parse_spec(old)
    # The dump holds the one form, which parses back to the same spec.
    new = load_spec(EXAMPLES_DIR / "push.yaml")
    dumped = new.model_dump(mode="json")
    assert dumped["task"]["type"] == "push" and "push" not in dumped
    assert parse_spec(dumped) == new


def test_task_registry_names_every_type():
    from sim.tasks import TASK_TYPES

    assert {"quiet_stance", "push", "pose_change", "sequence"} <= set(TASK_TYPES)
    for name, cls in TASK_TYPES.items():
        assert cls.model_fields["type"].default == name
