"""The `optimize.robust` block: validation at parse time (the field and the rule named), the
fixed variant set, and specs without the block keeping their canonical form."""

from __future__ import annotations

import copy
from pathlib import Path

import pytest
import yaml

from sim.errors import SpecError
from sim.robust import levels, variant_document, variant_values
from sim.spec import canonical_spec, parse_spec

DOMINO = yaml.safe_load((Path(__file__).resolve().parents[2] / "examples/domino.yaml"
                         ).read_text())


def robust_domino(**robust) -> dict:
    doc = copy.deepcopy(DOMINO)
    doc["optimize"] = {**doc["optimize"], "robust": robust}
    return doc


def test_one_path_takes_evenly_spaced_levels_ends_included() -> None:
    spec = parse_spec(robust_domino(vary={"task.mass": [112, 160]}, samples=5))
    assert variant_values(spec.optimize.robust) == [
        {"task.mass": m} for m in (112.0, 124.0, 136.0, 148.0, 160.0)]
    assert spec.optimize.robust.aggregate == "mean"
    assert levels(0.1, 0.7, 3)[-1] == 0.7 and levels(0.1, 0.7, 7)[0] == 0.1


def test_several_paths_form_a_latin_hypercube_fixed_by_the_block() -> None:
    vary = {"task.mass": [112, 160], "task.distance": [0.45, 0.55], "task.friction": [0.6, 1.0]}
    spec = parse_spec(robust_domino(vary=vary, samples=7))
    got = variant_values(spec.optimize.robust)
    assert len(got) == 7
    for path, (lo, hi) in vary.items():  # every level of every path used once
        assert sorted(v[path] for v in got) == levels(lo, hi, 7)
    # the first path (sorted) in order; the others permuted, not all in order
    assert [v["task.distance"] for v in got] == levels(0.45, 0.55, 7)
    assert [v["task.mass"] for v in got] != levels(112, 160, 7)
    # the same block in another key order and through the canonical text: the same variants
    again = parse_spec(robust_domino(vary=dict(reversed(vary.items())), samples=7))
    assert variant_values(again.optimize.robust) == got
    text = canonical_spec(spec)
    assert variant_values(parse_spec(text.document).optimize.robust) == got


def test_a_variant_is_an_ordinary_spec_at_its_values() -> None:
    spec = parse_spec(robust_domino(vary={"task.mass": [112, 160]}, samples=3))
    doc = variant_document(spec.model_dump(mode="json"), {"task.mass": 136.0})
    variant = parse_spec(doc)
    assert variant.task.mass == 136.0 and variant.optimize.robust is None


def test_specs_without_the_block_keep_their_canonical_form() -> None:
    plain = canonical_spec(parse_spec(copy.deepcopy(DOMINO)))
    assert "robust" not in plain.document["optimize"]
    robust = canonical_spec(parse_spec(robust_domino(vary={"task.mass": [112, 160]})))
    assert robust.document["optimize"]["robust"] == {
        "vary": {"task.mass": [112.0, 160.0]}, "samples": 5, "aggregate": "mean"}
    assert robust.hash != plain.hash


@pytest.mark.parametrize(("robust", "message"), [
    ({"vary": {"task.mass": [160, 112]}},
     "optimize.robust.vary.task.mass: the range must be [lo, hi] with lo < hi"),
    ({"vary": {"task.weight": [1, 2]}}, "optimize.robust.vary.task.weight: not a number"),
    ({"vary": {"cmrt.max_displacement": [0.1, 0.2]}},
     "optimize.robust.vary.cmrt.max_displacement: the cmrt block is not part of the scene"),
    ({"vary": {"cmrt.knots": [3, 5]}}, "optimize.robust.vary.cmrt.knots"),
    ({"vary": {"task.mass": [0.5, 160]}},
     "optimize.robust.vary.task.mass: the range [0.5, 160] must lie within the field's own "
     "range, 1 to 1000"),
    ({"vary": {"task.mass": [112, 160]}, "samples": 33},
     "optimize.robust.samples: must be from 2 to 32 variants, got 33"),
    ({"vary": {"task.mass": [112, 160]}, "samples": 1}, "optimize.robust.samples"),
    ({"vary": {}}, "optimize.robust.vary"),
    ({"vary": {f"task.{k}": [0.1, 0.2] for k in ("mass", "width", "height", "distance",
                                                  "friction")}}, "optimize.robust.vary"),
    ({"vary": {"task.mass": [112, 160]}, "aggregate": "median"}, "optimize.robust.aggregate"),
    ({"vary": {"task.mass": [112, 160, 170]}}, "optimize.robust.vary.task.mass"),
    ({"vary": {"task.mass": [112, float("nan")]}}, "optimize.robust.vary.task.mass"),
])
def test_a_bad_block_is_refused_naming_the_field_and_the_rule(robust, message) -> None:
    with pytest.raises(SpecError) as err:
        parse_spec(robust_domino(**robust), "d.yaml")
    assert message in str(err.value)
    assert str(err.value).startswith("d.yaml: ")


def test_every_variant_must_parse() -> None:
    # a domino stands on its narrow face (width below height 1.6 m): a width range reaching
    # past the height is refused at the variant that breaks the rule, naming its values
    parse_spec(robust_domino(vary={"task.width": [0.15, 0.3]}, samples=3))
    with pytest.raises(SpecError, match=r"d.yaml: optimize.robust: variant 2 "
                                        r"\(task.width = 1.8\) is not a valid spec: .*width "
                                        r"must be below height"):
        parse_spec(robust_domino(vary={"task.width": [0.15, 1.8]}, samples=3), "d.yaml")
