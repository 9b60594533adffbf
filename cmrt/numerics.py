"""The numeric kernels a product process runs with, pinned so that every worker computes the
same bits (docs/benchmarks.md, "Same bits on every worker").

The simulation does its linear algebra in its own compiled loops (`sim.linalg`), which do not
depend on the CPU. The optimiser's driver cannot: pycma's eigendecomposition and products go
through numpy's OpenBLAS, and numpy picks SIMD variants of its own functions by CPU, so the
same seeded CMA-ES gave different candidates under two BLAS kernels on one machine. Both
libraries choose their kernels once, when they are loaded, from the environment:

* `OPENBLAS_CORETYPE=Prescott`: OpenBLAS's SSE3 kernels, which every x86-64 CPU runs;
* `NPY_DISABLE_CPU_FEATURES`: numpy's dispatch above its SSE3 baseline switched off.

`pin_numeric_kernels` sets both in `os.environ` before numpy is imported; the entry packages
(`cli`, `service`, `worker`) call it first thing, so a `cmrt` command, an API server, a Celery
worker and the process pools they start (which inherit the environment) all run the same
kernels. The sizes here (CMA-ES in at most a few dozen dimensions) make the slower kernels'
cost negligible. Other CPU architectures keep their own kernels (the names are x86-64's).
"""

from __future__ import annotations

import os
import platform
import sys

#: The OpenBLAS kernel every x86-64 CPU can run (SSE3).
PINNED_BLAS_KERNEL = "Prescott"
#: numpy's dispatch targets above its x86-64 baseline (SSE, SSE2, SSE3), all switched off.
NUMPY_DISPATCH_OFF = ("SSSE3 SSE41 POPCNT SSE42 AVX F16C FMA3 AVX2 AVX512F AVX512CD "
                      "AVX512_KNL AVX512_KNM AVX512_SKX AVX512_CLX AVX512_CNL AVX512_ICL "
                      "AVX512_SPR")
#: The variables `pin_numeric_kernels` sets, and their values.
PINNED_ENVIRONMENT = {"OPENBLAS_CORETYPE": PINNED_BLAS_KERNEL,
                      "NPY_DISABLE_CPU_FEATURES": NUMPY_DISPATCH_OFF}


def pin_numeric_kernels() -> bool:
    """Set `PINNED_ENVIRONMENT` for this process and its children; True when it takes effect
    (an x86-64 machine, numpy not yet imported), False when it cannot (then nothing is set)."""
    if platform.machine().lower() not in ("x86_64", "amd64") or "numpy" in sys.modules:
        return False
    os.environ.update(PINNED_ENVIRONMENT)
    return True
