"""PCA basis: exact reconstruction, variance explained, box, duration pinning, files, search."""

from __future__ import annotations

import json

import numpy as np
import pytest
from synthetic import Sphere

from optim.errors import BasisError, ResultFileError
from optim.executors import SerialExecutor
from optim.pca import Basis, build_basis, build_basis_from_rows
from optim.result import OptimizationResult
from optim.run import optimize

DURATIONS = (0.3, 0.45, 0.6, 0.75, 0.9, 1.05, 1.2)


def subspace_rows(n=12, p=9, k=3, seed=0):
    rng = np.random.default_rng(seed)
    B = np.linalg.qr(rng.normal(size=(p, k)))[0].T  # (k, p) orthonormal
    Z = rng.normal(size=(n, k)) * [0.3, 0.1, 0.03]
    return 0.5 + Z @ B


def family_params(d: float) -> np.ndarray:
    w1 = np.linspace(-0.5, 0.5, 8)
    w2 = np.cos(np.arange(8))
    return np.clip(0.5 + (d - 0.7) * w1 + 0.05 * np.sin(5 * d) * w2, 0, 1)


@pytest.fixture
def family(make_spec):
    out = []
    for d in DURATIONS:
        spec = make_spec(f"bend_{d:g}", duration=d)
        out.append(
            OptimizationResult.build(spec, family_params(d), objective=d, baseline_objective=2.0)
        )
    return out


def test_reconstruction_exact_in_k_dim_subspace():
    rows = subspace_rows()
    b = build_basis_from_rows(rows, family="f", k=3)
    np.testing.assert_allclose(b.reconstruct(b.scores(rows)), rows, atol=1e-12)
    assert b.variance_explained.sum() == pytest.approx(1.0, abs=1e-12)
    assert b.variance_explained[:3].sum() == pytest.approx(1.0, abs=1e-12)
    assert np.all(np.diff(b.variance_explained) <= 1e-15)
    np.testing.assert_allclose(b.components @ b.components.T, np.eye(3), atol=1e-12)
    # fewer components lose the small directions
    b2 = build_basis_from_rows(rows, family="f", k=2)
    assert np.abs(b2.reconstruct(b2.scores(rows)) - rows).max() > 1e-4


def test_score_box_contains_members_with_margin():
    rows = subspace_rows()
    b = build_basis_from_rows(rows, family="f", k=3, margin=0.25)
    s = b.scores(rows)
    rng = s.max(0) - s.min(0)
    np.testing.assert_allclose(b.score_lo, s.min(0) - 0.25 * rng)
    np.testing.assert_allclose(b.score_hi, s.max(0) + 0.25 * rng)
    u = b.scores_to_box(s)
    assert np.all((u > 0.1) & (u < 0.9))
    np.testing.assert_allclose(b.box_to_scores(u), s, atol=1e-12)


def test_basis_errors():
    with pytest.raises(BasisError, match="too few"):
        build_basis_from_rows(subspace_rows(n=3), family="f", k=3)
    with pytest.raises(BasisError, match="identical"):
        build_basis_from_rows(np.ones((5, 9)), family="f", k=2)
    with pytest.raises(BasisError, match="k must be"):
        build_basis_from_rows(subspace_rows(), family="f", k=9)


def test_family_basis_decode_pins_duration(family, make_spec):
    b = build_basis(family, k=3)
    assert b.family == "bend" and b.members == [r.name for r in family] and b.dimension == 8
    for r in family:
        d = r.spec["clip"]["duration"]
        u = b.encode(r.params, d)
        np.testing.assert_allclose(b.decode(u, d), r.params, atol=1e-9)  # members reproduced
    rng = np.random.default_rng(0)
    for u in rng.random((20, 3)):
        z = b.pin_duration(b.box_to_scores(u), 0.5)
        assert b.reconstruct(z)[0, -1] == pytest.approx(0.5)
        p = b.decode(u, 0.5)
        assert p.shape == (8,) and np.all((p >= 0) & (p <= 1))
    # the family's params are a function of duration: pinning recovers an unseen member
    # up to the small sin-term direction
    near = b.decode(b.encode(family_params(0.5), 0.5), 0.5)
    np.testing.assert_allclose(near, family_params(0.5), atol=0.02)
    b.check_spec(make_spec(duration=0.5))
    with pytest.raises(BasisError, match="spline parameters"):
        b.check_spec(make_spec(knots=5))


def test_basis_file_round_trip_and_tamper(family, tmp_path):
    b = build_basis(family, k=3)
    path = tmp_path / "basis.json"
    b.save(path)
    back = Basis.load(path)
    assert back.id == b.id
    np.testing.assert_array_equal(back.components, b.components)
    data = json.loads(path.read_text())
    data["mean"][0] += 0.01
    with pytest.raises(ResultFileError, match="'id'"):
        Basis.from_dict(data, "x.json")
    del data["components"]
    with pytest.raises(ResultFileError, match="missing field 'components'"):
        Basis.from_dict(data, "x.json")


def test_mixed_family_rejected(family, make_spec):
    odd = OptimizationResult.build(
        make_spec("push_1", family="push"), family_params(0.5), objective=1, baseline_objective=2
    )
    with pytest.raises(BasisError, match="family"):
        build_basis([*family, odd])


def test_optimize_in_reduced_space(family, make_spec):
    b = build_basis(family, k=3)
    spec = make_spec("bend_new", duration=0.5, min_evaluations=40, window=3, max_evaluations=80)
    target = family_params(0.5)
    fn = Sphere(centre=0.0)  # any objective; check plumbing, determinism and decoding

    res = optimize(spec, SerialExecutor(), seed=1, basis=b, objective=fn)
    assert res.basis_id == b.id and len(res.reduced_params) == 3 and len(res.params) == 8
    np.testing.assert_allclose(res.params, b.decode(res.reduced_params, 0.5))
    again = optimize(spec, SerialExecutor(), seed=1, basis=b, objective=fn)
    assert again.params == res.params
    warm = optimize(spec, SerialExecutor(), seed=1, basis=b, objective=fn, x0=target)
    assert warm.basis_id == b.id


def test_initial_point(family, make_spec):
    from optim.run import initial_point
    from optim.spline import flat_params

    b = build_basis(family, k=3)
    spec = make_spec(duration=0.6)
    np.testing.assert_array_equal(initial_point(spec), flat_params(spec))
    np.testing.assert_array_equal(initial_point(spec, basis=b), np.full(3, 0.5))
    u = initial_point(spec, basis=b, x0=family_params(0.6))
    assert u.shape == (3,) and np.all((u >= 0) & (u <= 1))
