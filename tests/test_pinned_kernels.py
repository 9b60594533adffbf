"""The test process runs the kernels every product process runs (tests/conftest.py pins them
before any test module imports numpy): a run in this process and the same run in a server or
worker process compare by `repr`."""

from __future__ import annotations

import os
import platform

import pytest

from cmrt.numerics import PINNED_ENVIRONMENT


@pytest.mark.skipif(platform.machine().lower() not in ("x86_64", "amd64"),
                    reason="the pinned kernels are x86-64's")
def test_the_suite_runs_the_pinned_kernels():
    from numpy._core._multiarray_umath import __cpu_features__ as features

    for key, value in PINNED_ENVIRONMENT.items():
        assert os.environ.get(key) == value
    assert features["SSE3"] and not features["AVX2"]  # numpy loaded after the pin
