"""CMRT spline: end conditions, knot ordering, flat spline, encoding round trip."""

from __future__ import annotations

import pickle

import numpy as np
import pytest

from optim.errors import ParamsError
from optim.spline import (
    CmrtSpline,
    check_params,
    clamped_cubic_coefficients,
    decode,
    encode,
    flat_params,
    min_knot_gap,
    sample_curve,
)


def test_flat_spline_is_exactly_zero(make_spec):
    for knots, vertical in [(4, False), (1, False), (6, True)]:
        spec = make_spec(knots=knots, vertical=vertical)
        s = decode(spec, flat_params(spec))
        ts = np.linspace(-1.0, spec.clip.length + 1.0, 1001)
        assert np.all(s.sample(ts) == 0.0)
        assert all(s(t) == 0.0 or s(t) == (0.0, 0.0) for t in ts[::50])
        assert np.all(s.values == 0.0)
        gaps = np.diff(np.concatenate(([0.0], s.knot_times, [spec.clip.length])))
        np.testing.assert_allclose(gaps[1:-1], spec.clip.length / knots)  # equally spaced


@pytest.mark.parametrize("seed", range(5))
def test_end_conditions_zero_value_and_slope(make_spec, seed):
    spec = make_spec(vertical=True)
    rng = np.random.default_rng(seed)
    s = decode(spec, rng.random(spec.cmrt_dimension))
    L = spec.clip.length
    assert s(0.0) == (0.0, 0.0)
    assert s(L) == (0.0, 0.0)
    for comp in (0, 1):
        d = s.derivative([0.0, L], component=comp)
        assert np.all(np.abs(d) < 1e-9)
    # continuity at the ends: tiny steps inside stay ~0 (value and slope both vanish)
    near = s.sample([1e-4, L - 1e-4])
    assert np.all(np.abs(near) < 1e-5)
    # zero outside the clip
    assert np.all(s.sample([-0.5, -1e-9, L + 1e-9, L + 3]) == 0.0)


def test_spline_interpolates_knots_and_is_c2():
    x = np.array([0.0, 0.3, 0.9, 1.4, 2.0])
    y = np.array([0.0, 0.1, -0.05, 0.02, 0.0])
    c = clamped_cubic_coefficients(x, y)
    h = np.diff(x)
    ends = c[:, 0] + c[:, 1] * h + c[:, 2] * h**2 + c[:, 3] * h**3
    np.testing.assert_allclose(ends, y[1:], atol=1e-12)  # continuity
    slope_end = c[:, 1] + 2 * c[:, 2] * h + 3 * c[:, 3] * h**2
    np.testing.assert_allclose(slope_end[:-1], c[1:, 1], atol=1e-12)  # C1
    curv_end = 2 * c[:, 2] + 6 * c[:, 3] * h
    np.testing.assert_allclose(curv_end[:-1], 2 * c[1:, 2], atol=1e-10)  # C2
    assert c[0, 1] == pytest.approx(0.0, abs=1e-12) and slope_end[-1] == pytest.approx(0, abs=1e-12)
    s = CmrtSpline(2.0, x[1:-1], y[1:-1])
    np.testing.assert_allclose(s.sample(x[1:-1]), y[1:-1], atol=1e-12)


def test_knots_ordered_with_min_gap_for_random_params(make_spec):
    rng = np.random.default_rng(42)
    for knots in (1, 2, 4, 8, 16):
        for duration in (0.1, 0.4, 3.0):
            spec = make_spec(knots=knots, duration=duration)
            L = spec.clip.length
            g = min_knot_gap(L, knots)
            P = rng.random((200, spec.cmrt_dimension))
            P[:3, :knots] = [[0.0], [1.0], [0.5]]  # extremes
            P[3, :knots] = np.tile([1.0, 0.0], knots)[:knots]  # adjacent knots pushed together
            for p in P:
                kt = decode(spec, p).knot_times
                assert kt[0] >= g / 2 - 1e-12 and kt[-1] <= L - g / 2 + 1e-12
                assert np.all(np.diff(kt) >= g - 1e-12)


def test_value_decoding_range(make_spec):
    spec = make_spec(vertical=True)
    p = flat_params(spec)
    p[4], p[5] = 0.0, 1.0
    p[8] = 1.0
    s = decode(spec, p)
    assert s.values[0] == -spec.cmrt.max_displacement
    assert s.values[1] == spec.cmrt.max_displacement
    assert s.vertical_values[0] == spec.cmrt.max_vertical
    assert s.values[2] == 0.0


def test_encode_decode_round_trip_and_dict(make_spec):
    spec = make_spec(vertical=True)
    p = np.random.default_rng(1).random(spec.cmrt_dimension)
    s = decode(spec, p)
    np.testing.assert_allclose(encode(spec, s), p, atol=1e-12)
    s2 = CmrtSpline.from_dict(s.to_dict())
    ts = np.linspace(0, spec.clip.length, 77)
    np.testing.assert_array_equal(s2.sample(ts), s.sample(ts))
    s3 = pickle.loads(pickle.dumps(s))
    assert s3(1.23) == s(1.23)
    curve = sample_curve(s)
    assert len(curve["t"]) == 100 and set(curve) == {"t", "dx", "dy"}


def test_scalar_and_vector_agree(make_spec):
    spec = make_spec()
    s = decode(spec, np.random.default_rng(3).random(8))
    ts = np.linspace(-0.1, spec.clip.length + 0.1, 301)
    np.testing.assert_allclose([s(t) for t in ts], s.sample(ts), atol=1e-15)
    assert isinstance(s(1.0), float)


def test_bad_params_rejected(make_spec):
    spec = make_spec()
    with pytest.raises(ParamsError, match="expected 8"):
        decode(spec, np.zeros(7))
    with pytest.raises(ParamsError, match="finite"):
        decode(spec, np.full(8, np.nan))
    np.testing.assert_array_equal(check_params(spec, np.full(8, 1.5)), np.ones(8))
    with pytest.raises(ParamsError, match="strictly increasing"):
        CmrtSpline(2.0, [0.5, 0.4], [0.0, 0.0])
    with pytest.raises(ParamsError, match="missing field 'values'"):
        CmrtSpline.from_dict({"length": 2.0, "knot_times": [1.0]})
