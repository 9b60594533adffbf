"""Interpolation along a task parameter, and superposition of CMRTs."""

from __future__ import annotations

import pickle

import numpy as np
import pytest

from optim.errors import InterpolationError
from optim.interpolate import interpolate
from optim.result import OptimizationResult
from optim.spline import CmrtSpline, decode
from optim.superpose import superpose


@pytest.fixture
def results(make_spec):
    rng = np.random.default_rng(5)
    out = []
    for d in (0.4, 0.8, 1.2):
        spec = make_spec(f"bend_{d:g}", duration=d)
        out.append(
            OptimizationResult.build(spec, rng.random(8), objective=1.0 + d, baseline_objective=3)
        )
    return out


def test_sample_points_returned_exactly(results):
    for r in results:
        d = r.spec["clip"]["duration"]
        it = interpolate(results, d)
        assert it.exact and not it.extrapolated
        np.testing.assert_array_equal(it.knot_times, r.knot_times)
        np.testing.assert_array_equal(it.values, r.values)
        assert it.length == r.length
        ts = np.linspace(0, r.length, 50)
        np.testing.assert_array_equal(it.spline().sample(ts), r.spline().sample(ts))


def test_midpoint_is_linear_in_knots_and_values(results, make_spec):
    a, b = results[0], results[1]
    it = interpolate(results, 0.6)
    assert (it.lower, it.upper, it.weight) == (a.name, b.name, pytest.approx(0.5))
    np.testing.assert_allclose(it.knot_times, (np.array(a.knot_times) + b.knot_times) / 2)
    np.testing.assert_allclose(it.values, (np.array(a.values) + b.values) / 2)
    assert it.length == pytest.approx(2.6)
    it.spline()  # valid, ordered knots
    spec = make_spec(duration=0.6)
    p = it.params(spec)
    np.testing.assert_allclose(decode(spec, p).values, it.values, atol=1e-12)
    assert it.to_dict()["extrapolated"] is False


def test_out_of_range_needs_extrapolate(results):
    with pytest.raises(InterpolationError, match="outside the sampled range"):
        interpolate(results, 1.3)
    it = interpolate(results, 1.3, extrapolate=True)
    assert it.extrapolated and it.weight == pytest.approx(1.25)
    assert (it.lower_value, it.upper_value) == (0.8, 1.2)
    lo = interpolate(results, 0.35, extrapolate=True)
    assert lo.extrapolated and lo.weight < 0


def test_domain_errors(results, make_spec):
    with pytest.raises(InterpolationError, match="at least 2"):
        interpolate(results[:1], 0.4)
    with pytest.raises(InterpolationError, match="2 distinct"):
        interpolate([results[0], results[0]], 0.4)
    with pytest.raises(InterpolationError, match="no task parameter 'force'"):
        interpolate(results, 100.0, key="force")
    other = OptimizationResult.build(
        make_spec("p", family="push"), np.full(8, 0.5), objective=1, baseline_objective=1
    )
    with pytest.raises(InterpolationError, match="different families"):
        interpolate([*results, other], 0.5)


def test_duplicates_keep_the_best(results, make_spec):
    worse = OptimizationResult.build(
        make_spec("bend_0.4_b", duration=0.4), np.full(8, 0.5), objective=99, baseline_objective=1
    )
    it = interpolate([worse, *results], 0.4)
    assert it.lower == results[0].name


def test_superposition_sums_shifted_splines():
    a = CmrtSpline(2.0, [0.5, 1.0, 1.5], [0.05, -0.08, 0.02])
    b = CmrtSpline(1.5, [0.3, 0.9], [-0.03, 0.04])
    comp = superpose([(0.0, a), (1.2, b)])
    ts = np.linspace(-0.5, 3.5, 401)
    expected = a.sample(ts) + b.sample(ts - 1.2)
    np.testing.assert_allclose(comp.sample(ts), expected, atol=1e-15)
    np.testing.assert_allclose([comp(t) for t in ts], expected, atol=1e-15)
    assert comp(0.7) == pytest.approx(a(0.7))  # before b starts
    assert comp(3.0) == pytest.approx(0.0)  # after both end
    assert comp.end == pytest.approx(2.7)
    assert pickle.loads(pickle.dumps(comp))(1.7) == comp(1.7)


def test_superposition_mixed_vertical():
    a = CmrtSpline(2.0, [1.0], [0.05], vertical_values=[-0.02])
    b = CmrtSpline(2.0, [1.0], [0.01])
    comp = superpose([(0.0, a), (0.5, b)])
    dx, dy = comp(1.2)
    assert dx == pytest.approx(a(1.2)[0] + b(0.7)) and dy == pytest.approx(a(1.2)[1])
    assert comp.sample([1.2]).shape == (1, 2)
