"""Recording beside the rollout: replay frames (poses of every body and prop) and traces."""

from __future__ import annotations

import json

import numpy as np
import pytest

from sim.recording import FRAME_EVERY, FRAME_RATE
from sim.rollout import Rollout
from sim.spec import parse_spec


@pytest.fixture(scope="module")
def recorded():
    spec = parse_spec({"name": "rec", "task": {"type": "push", "force": 60.0},
                       "clip": {"preparation": 0.2, "duration": 0.1, "decay": 0.2}})
    sim = Rollout(spec)
    try:
        yield sim, sim.run(traces=True), sim.run()
    finally:
        sim.close()


def test_frames_hold_every_body_at_the_frame_rate(recorded):
    sim, ev, _ = recorded
    f = ev.frames
    n = len(f.t)
    assert f.rate == FRAME_RATE and FRAME_EVERY == 10
    assert n == -(-ev.steps // FRAME_EVERY)
    np.testing.assert_allclose(f.t, np.arange(n) / FRAME_RATE, atol=1e-12)
    assert f.names == list(sim.character.body_names)
    assert all(len(p) == len(f.names) for p in f.poses)
    assert len(f.cm) == len(f.cm_ref) == len(f.cp) == len(f.support) == n
    # Frame 0 is the reset state: the standing pose's root, the support's heel and toe.
    x, y, a = f.poses[0][0]
    assert (x, y, a) == pytest.approx(tuple(sim.q0[:3]), abs=1e-9)
    lo, hi = f.support[0]
    assert hi - lo == pytest.approx(sim.support_length, abs=1e-6)
    # The frames' CM matches the 1 kHz trace's CM of the step that starts at that time.
    k = FRAME_EVERY * 5
    np.testing.assert_allclose(f.cm[5], ev.traces.cm[k], atol=0)


def test_frames_are_json_and_do_not_change_the_simulation(recorded):
    _sim, ev, quick = recorded
    d = ev.to_dict(include_traces=True)
    text = json.dumps(d, allow_nan=False)
    back = json.loads(text)
    assert back["frames"]["names"][0] == "pelvis" and len(back["frames"]["poses"]) == len(
        ev.frames.t)
    assert back["fall_direction"] is None and back["task_success"] is None
    assert "frames" not in ev.to_dict() and "traces" not in ev.to_dict()
    assert quick.objective == ev.objective and quick.steps == ev.steps
