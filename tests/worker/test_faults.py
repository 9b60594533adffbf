"""The fault-injection hooks (worker/faults.py): patterns, validation, off by default."""

from __future__ import annotations

import pytest

from worker import faults


def test_unset_hooks_do_nothing(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.delenv(faults.ENV, raising=False)
    monkeypatch.delenv(faults.DELAY_ENV, raising=False)
    assert not faults.should_crash("poison", 0, 1)
    assert faults.delay_for("anything", 1, 0) == 0.0


def test_crash_patterns_match_name_generation_and_index(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv(faults.ENV, "poison:0:1, other:*:3")
    assert faults.should_crash("poison", 0, 1)
    assert not faults.should_crash("poison", 1, 1)
    assert not faults.should_crash("poisoned", 0, 1)
    assert faults.should_crash("other", 7, 3)


def test_delay_patterns_sum_their_seconds(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv(faults.DELAY_ENV, "it_fault_*:1:0:2.5,*:1:*:0.5")
    assert faults.delay_for("it_fault_kill", 1, 0) == pytest.approx(3.0)
    assert faults.delay_for("it_fault_kill", 1, 4) == pytest.approx(0.5)
    assert faults.delay_for("it_fault_kill", 0, 0) == 0.0


@pytest.mark.parametrize("value, needle", [
    ("a:1:0", "NAME:GENERATION:INDEX:SECONDS"),
    ("a:1:0:soon", "is not a number"),
    ("a:1:0:-1", "must be in [0, 600]"),
])
def test_bad_delay_patterns_name_the_rule(monkeypatch: pytest.MonkeyPatch, value: str,
                                          needle: str) -> None:
    monkeypatch.setenv(faults.DELAY_ENV, value)
    with pytest.raises(ValueError, match="CMRT_FAULT_DELAY_ON") as err:
        faults.delay_for("a", 1, 0)
    assert needle in str(err.value)


def test_bad_crash_pattern_names_the_form(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv(faults.ENV, "poison:0")
    with pytest.raises(ValueError, match="NAME:GENERATION:INDEX"):
        faults.should_crash("poison", 0, 1)
