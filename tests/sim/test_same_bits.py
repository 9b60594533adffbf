"""The same bits whatever BLAS kernel a worker's CPU gives it: clips, the numeric fingerprint,
and an optimisation run through the `cmrt` command, each computed under two OpenBLAS kernels in
child processes."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
#: Two OpenBLAS kernels of different SIMD width and blocking (SSE3; AVX2 with FMA).
KERNELS = ("Prescott", "Haswell")

#: The child: no product entry point is imported, so nothing pins the kernel the parent gave.
CLIPS = """
import json, sys
from sim import evaluate, load_spec
from sim.fingerprint import numeric_fingerprint
out = {"fingerprint": numeric_fingerprint().to_dict()}
for name in ("fast_bend", "step_push"):
    ev = evaluate(load_spec(f"examples/{name}.yaml"), None, traces=True)
    d = ev.to_dict(include_traces=True)
    out[name] = {"objective": repr(ev.objective), "fell": ev.fell,
                 "traces": json.dumps(d.get("traces"), sort_keys=True)}
json.dump(out, sys.stdout)
"""

SHORT_RUN = """name: short_bend
clip: {preparation: 1.0, duration: 0.4, decay: 0.6}
task: {type: pose_change, target: {waist: -90, shoulder_r: 90, shoulder_l: 90}}
optimize: {popsize: 4, min_evaluations: 0, max_evaluations: 8}
"""


def _cpu_flags() -> set[str]:
    """The CPU's feature flags as Linux names them (SSE3 is "pni"); empty elsewhere."""
    try:
        text = Path("/proc/cpuinfo").read_text()
    except OSError:
        return set()
    line = next((x for x in text.splitlines() if x.startswith("flags")), "")
    return set(line.split(":", 1)[-1].split())


def _kernel_env(kernel: str) -> dict[str, str]:
    env = {k: v for k, v in os.environ.items()
           if k not in ("OPENBLAS_CORETYPE", "NPY_DISABLE_CPU_FEATURES")}
    env["OPENBLAS_CORETYPE"] = kernel
    return env


pytestmark = pytest.mark.skipif(not {"avx2", "fma", "pni"} <= _cpu_flags(),
                                reason="needs an x86-64 CPU that runs both kernels")


def test_clips_and_the_fingerprint_are_the_same_bits_under_two_blas_kernels() -> None:
    out = [json.loads(subprocess.run([sys.executable, "-c", CLIPS], cwd=ROOT, check=True,
                                     capture_output=True, text=True,
                                     env=_kernel_env(k)).stdout) for k in KERNELS]
    assert out[0] == out[1]
    assert out[0]["fast_bend"]["traces"] != "null"
    assert len(out[0]["fingerprint"]["fingerprint"]) == 16


def test_a_seeded_optimisation_is_the_same_bits_under_two_blas_kernels(tmp_path: Path) -> None:
    spec = tmp_path / "short_bend.yaml"
    spec.write_text(SHORT_RUN)
    cmrt = str(Path(sys.executable).with_name("cmrt"))
    results = []
    for k in KERNELS:
        out = tmp_path / f"{k}.json"
        subprocess.run([cmrt, "optimize", str(spec), "--seed", "3", "--out", str(out)],
                       cwd=ROOT, check=True, capture_output=True, env=_kernel_env(k))
        results.append(json.loads(out.read_text()))
    a, b = results
    assert a["evaluations"] == b["evaluations"] >= 8
    assert repr(a["objective"]) == repr(b["objective"])
    assert repr(a["history"]) == repr(b["history"])
    assert [repr(x) for x in a["params"]] == [repr(x) for x in b["params"]]


@pytest.mark.parametrize("entry", ["cli", "service", "worker"])
def test_the_entry_points_pin_the_kernels_before_numpy_loads(entry: str) -> None:
    probe = (f"import {entry}, os, numpy\n"
             "from numpy._core._multiarray_umath import __cpu_features__ as f\n"
             "print(os.environ['OPENBLAS_CORETYPE'], f['AVX2'])")
    out = subprocess.run([sys.executable, "-c", probe], cwd=ROOT, check=True,
                         capture_output=True, text=True, env=_kernel_env("Haswell")).stdout
    assert out.split() == ["Prescott", "False"]
