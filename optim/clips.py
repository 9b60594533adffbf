"""The bodies of a what-if clip, run in a process of the API's simulation pool
(`application.simulations.SimulationPool`): picklable functions of a spec document and a
parameter vector that answer `{"status": "done", ...}`, or `{"status": "failed", "error": ...}`
when the simulator refuses the clip or it diverges.

They import only the simulator (no store, no web code), so a pool process that unpickles one
loads nothing beyond what its fork server has already imported (`procpool.SIMULATOR_PRELOAD`)
but the replay and export writers.
"""

from __future__ import annotations

import math
from typing import Any

from optim.objective import SimObjective
from optim.spline import decode
from sim.errors import SimError
from sim.export import export_text
from sim.replay import ReplayClip, build_replay

#: The outcome fields copied from sim's Evaluation.
OUTCOME_FIELDS = ("objective", "fell", "fall_time", "fall_reason", "fall_direction",
                  "task_success", "task_penalty", "error_norm", "max_abs_error", "sim_seconds",
                  "cpu_seconds", "steps", "contact_steps", "cmrt_released_at")


#: How a clip fails in a pool process: the simulator's refusals (DivergenceError, ...), and
#: numbers gone non-finite past its checks (numpy's LinAlgError is a ValueError): the clip
#: diverged between two checks.
CLIP_FAILURES = (SimError, ArithmeticError, ValueError)


def clip_failure(err: Exception) -> dict[str, Any]:
    """The `failed` outcome of a clip that raised one of CLIP_FAILURES, with the reason."""
    if isinstance(err, SimError):
        return {"status": "failed", "error": f"{type(err).__name__}: {err}"}
    return {"status": "failed", "error": f"the simulation diverged ({type(err).__name__}: {err})"}


def _finite_or_none(v: Any) -> Any:
    return None if isinstance(v, float) and not math.isfinite(v) else v


def run_clip(spec_data: dict[str, Any], params: list[float] | None, traces: bool,
             frames: bool) -> dict[str, Any]:
    """Simulate one clip (in a pool process): `{"status": "done", ...outcome}` or
    `{"status": "failed", "error": ...}` when the simulator refuses or diverges."""
    try:
        ev = SimObjective(spec_data).evaluation(params, traces=traces or frames)
    except CLIP_FAILURES as err:
        return clip_failure(err)
    out: dict[str, Any] = {"status": "done"}
    out.update({k: _finite_or_none(getattr(ev, k)) for k in OUTCOME_FIELDS})
    full = ev.to_dict(include_traces=True)
    if traces:
        out["traces"] = full.get("traces")
    if frames:
        out["frames"] = full.get("frames")
    return out


def run_replay(spec_data: dict[str, Any], params: list[float] | None,
               about: dict[str, Any] | None, compare: bool) -> dict[str, Any]:
    """Simulate a clip for replay (in a pool process), recorded at the frame rate:
    `{"status": "done", "replay": <sim.replay document>}`, or `failed` as `run_clip`. With
    `params` and `compare`, the flat-spline clip (no anticipation) comes first, beside it."""
    obj = SimObjective(spec_data)
    spec = obj.spec
    clips = []
    try:
        if params is None or compare:
            clips.append(ReplayClip("no anticipation (flat spline)",
                                    obj.evaluation(None, traces=True), None, {"source": "none"}))
        if params is not None:
            clips.append(ReplayClip("with the CMRT", obj.evaluation(params, traces=True),
                                    decode(spec, params), about))
    except CLIP_FAILURES as err:
        return clip_failure(err)
    return {"status": "done", "replay": build_replay(spec, clips)}


def run_export(spec_data: dict[str, Any], params: list[float], fmt: str, fps: float
               ) -> dict[str, Any]:
    """Simulate the clip of `params` (in a pool process) and write its motion as `fmt` ("bvh"
    or "csv", `sim.export`) at `fps`: `{"status": "done", "text": ...}`, or `failed` as
    `run_clip`."""
    obj = SimObjective(spec_data)
    try:
        ev = obj.evaluation(params, traces=True)
        text = export_text(obj.spec.load_character(), ev, fmt, fps)
    except CLIP_FAILURES as err:
        return clip_failure(err)
    return {"status": "done", "text": text}


__all__ = ["CLIP_FAILURES", "OUTCOME_FIELDS", "clip_failure", "run_clip", "run_export",
           "run_replay"]
