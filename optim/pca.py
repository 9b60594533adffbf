"""PCA basis of a family of CMRTs and the reduced search space (paper section 5).

Data matrix: one row per optimised result of the family, p = d + 1 columns: the d spline
parameters (optim.spline encoding, all in [0, 1]) followed by the task duration in seconds
(`spec.clip.duration`, the paper's "motion length" column, which lets members of different
durations share one basis). Rows are centred on their mean and decomposed, A - mean = U S V^T.
The first k rows of V^T are the `components` (unit length; sign fixed so that each
component's largest-magnitude entry is positive), `variance_explained` = S^2 / sum(S^2) for all
min(n, p) components (sums to 1), and the members' scores are (A - mean) V_k.

Reduced search (`optimize(..., basis=...)`): CMA-ES searches u in [0, 1]^k. The score box is
[min, max] of the members' scores per component, widened on each side by `margin` times the
range (default 25 %; a component whose range is ~0 gets +-MIN_BOX_HALF_WIDTH instead), and
z = lo + u (hi - lo). Decoding (`Basis.decode(u, duration)`):
  * duration constraint (fix_duration=True, default): the reconstructed duration column
    mean_p + z . v (v = the components' duration entries) must equal the target task's
    duration T. z is replaced by its orthogonal projection onto that hyperplane,
    z' = z + (T - mean_p - z . v) v / |v|^2. So the search explores the other k - 1
    directions freely and the component(s) correlated with duration are pinned to the target.
    If |v| is ~0 (duration does not vary in the family) there is nothing to pin and z is kept.
  * params = clip(mean[:d] + z' V_k[:, :d], 0, 1); the duration column is then dropped.
A basis only fits specs with the same CmrtConfig (knots, vertical, maximum displacements):
`Basis.check_spec` raises BasisError otherwise.
"""

from __future__ import annotations

import hashlib
import json
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from optim._io import atomic_write_text, read_json_file
from optim.errors import BasisError, ResultFileError
from sim.spec import CmrtConfig

if TYPE_CHECKING:
    from optim.sample import CmrtSample
    from sim.spec import TaskSpec

#: Default number of kept components (paper: k = 3).
DEFAULT_K = 3
#: Default widening of the score box, as a fraction of the members' score range per side.
DEFAULT_MARGIN = 0.25
#: Half width of the box (parameter units) for a component whose members' range is ~0.
MIN_BOX_HALF_WIDTH = 0.05
#: |v|^2 below which the duration column is treated as not represented by the components.
_DURATION_EPS = 1e-12
BASIS_FORMAT = "cmrt-basis/1"
DURATION_COLUMN = "duration"


@dataclass
class Basis:
    """A PCA basis of one family (see module docstring). Arrays are float64."""

    family: str
    k: int
    mean: np.ndarray  # (p,)
    components: np.ndarray  # (k, p), orthonormal rows
    variance_explained: np.ndarray  # (min(n, p),), sums to 1
    members: list[str]
    score_lo: np.ndarray  # (k,)
    score_hi: np.ndarray  # (k,)
    cmrt: dict[str, Any] = field(default_factory=dict)  # CmrtConfig the params were encoded with
    margin: float = DEFAULT_MARGIN
    column: str = DURATION_COLUMN

    # -- derived -------------------------------------------------------------------------------
    @property
    def dimension(self) -> int:
        """Number of spline parameters d (p - 1)."""
        return int(self.mean.shape[0]) - 1

    @property
    def id(self) -> str:
        """Stable content id: '<family>-k<k>-<10 hex digits of a SHA-256 of the basis>'."""
        body = json.dumps(self._body(), sort_keys=True, separators=(",", ":"))
        digest = hashlib.sha256(body.encode()).hexdigest()[:10]
        return f"{self.family}-k{self.k}-{digest}"

    def check_spec(self, spec: TaskSpec) -> None:
        """BasisError unless `spec` uses this basis' parameter layout and CMRT settings."""
        if spec.cmrt_dimension != self.dimension:
            raise BasisError(
                f"basis {self.id!r} has {self.dimension} spline parameters, "
                f"spec {spec.name!r} needs {spec.cmrt_dimension}"
            )
        if self.cmrt and spec.cmrt.model_dump() != self.cmrt:
            raise BasisError(
                f"basis {self.id!r} was built with cmrt settings {self.cmrt}, "
                f"spec {spec.name!r} uses {spec.cmrt.model_dump()}"
            )

    # -- maps ----------------------------------------------------------------------------------
    def scores(self, rows: np.ndarray) -> np.ndarray:
        """Scores (n, k) of full rows (n, p) (params + duration)."""
        return (np.atleast_2d(np.asarray(rows, dtype=float)) - self.mean) @ self.components.T

    def reconstruct(self, scores: np.ndarray) -> np.ndarray:
        """Full rows (n, p) from scores (n, k)."""
        return self.mean + np.atleast_2d(np.asarray(scores, dtype=float)) @ self.components

    def box_to_scores(self, u: Sequence[float] | np.ndarray) -> np.ndarray:
        """z = lo + u (hi - lo) for u in [0, 1]^k (not clipped)."""
        return self.score_lo + np.asarray(u, dtype=float) * (self.score_hi - self.score_lo)

    def scores_to_box(self, z: Sequence[float] | np.ndarray) -> np.ndarray:
        """Inverse of `box_to_scores`, clipped into [0, 1]^k."""
        u = (np.asarray(z, dtype=float) - self.score_lo) / (self.score_hi - self.score_lo)
        return np.clip(u, 0.0, 1.0)

    def pin_duration(self, z: np.ndarray, duration: float) -> np.ndarray:
        """Project scores z onto {z : reconstructed duration column == duration}."""
        v = self.components[:, -1]
        vv = float(v @ v)
        if vv < _DURATION_EPS:
            return np.asarray(z, dtype=float)
        gap = float(duration) - (self.mean[-1] + float(np.asarray(z) @ v))
        return np.asarray(z, dtype=float) + gap * v / vv

    def decode(
        self, u: Sequence[float] | np.ndarray, duration: float, *, fix_duration: bool = True
    ) -> np.ndarray:
        """Full spline params (d,) in [0, 1] for box point u and the target task duration (s)."""
        u = np.asarray(u, dtype=float).reshape(-1)
        if len(u) != self.k:
            raise BasisError(f"basis {self.id!r}: expected {self.k} coefficients, got {len(u)}")
        z = self.box_to_scores(u)
        if fix_duration:
            z = self.pin_duration(z, duration)
        row = self.reconstruct(z)[0]
        return np.clip(row[:-1], 0.0, 1.0)

    def encode(self, params: Sequence[float] | np.ndarray, duration: float) -> np.ndarray:
        """Box point u in [0, 1]^k closest (least squares) to params at this duration."""
        p = np.asarray(params, dtype=float).reshape(-1)
        if len(p) != self.dimension:
            raise BasisError(f"basis {self.id!r}: expected {self.dimension} params, got {len(p)}")
        z = self.scores(np.append(p, float(duration)))[0]
        return self.scores_to_box(z)

    # -- (de)serialisation -----------------------------------------------------------------------
    def _body(self) -> dict[str, Any]:
        return {
            "format": BASIS_FORMAT,
            "family": self.family,
            "k": self.k,
            "column": self.column,
            "margin": self.margin,
            "cmrt": self.cmrt,
            "members": list(self.members),
            "mean": [float(v) for v in self.mean],
            "components": [[float(v) for v in row] for row in self.components],
            "variance_explained": [float(v) for v in self.variance_explained],
            "score_lo": [float(v) for v in self.score_lo],
            "score_hi": [float(v) for v in self.score_hi],
        }

    def to_dict(self) -> dict[str, Any]:
        d = self._body()
        d["id"] = self.id
        return d

    @classmethod
    def from_dict(cls, data: Any, source: str = "<basis>") -> Basis:
        """Validate and build; ResultFileError naming `source` and the field on bad data."""
        if not isinstance(data, Mapping):
            raise ResultFileError(f"{source}: a basis must be a JSON object")
        if data.get("format", BASIS_FORMAT) != BASIS_FORMAT:
            raise ResultFileError(f"{source}: field 'format': unsupported {data.get('format')!r}")
        for key in (
            "family",
            "k",
            "mean",
            "components",
            "variance_explained",
            "score_lo",
            "score_hi",
        ):
            if key not in data:
                raise ResultFileError(f"{source}: missing field {key!r}")

        def arr(key: str, ndim: int) -> np.ndarray:
            try:
                a = np.asarray(data[key], dtype=float)
            except (TypeError, ValueError):
                raise ResultFileError(f"{source}: field {key!r} must hold numbers") from None
            if a.ndim != ndim or not np.all(np.isfinite(a)):
                raise ResultFileError(
                    f"{source}: field {key!r} must be a {ndim}-D array of finite numbers"
                )
            return a

        k = data["k"]
        if not isinstance(k, int) or isinstance(k, bool) or k < 1:
            raise ResultFileError(f"{source}: field 'k' must be a positive integer")
        mean = arr("mean", 1)
        comps = arr("components", 2)
        if comps.shape != (k, mean.shape[0]):
            raise ResultFileError(
                f"{source}: field 'components' has shape {comps.shape}, expected "
                f"({k}, {mean.shape[0]})"
            )
        lo, hi = arr("score_lo", 1), arr("score_hi", 1)
        if lo.shape != (k,) or hi.shape != (k,) or np.any(hi <= lo):
            raise ResultFileError(
                f"{source}: fields 'score_lo'/'score_hi' must hold {k} numbers with lo < hi"
            )
        basis = cls(
            family=str(data["family"]),
            k=k,
            mean=mean,
            components=comps,
            variance_explained=arr("variance_explained", 1),
            members=[str(m) for m in data.get("members", [])],
            score_lo=lo,
            score_hi=hi,
            cmrt=dict(data.get("cmrt") or {}),
            margin=float(data.get("margin", DEFAULT_MARGIN)),
            column=str(data.get("column", DURATION_COLUMN)),
        )
        if "id" in data and data["id"] != basis.id:
            raise ResultFileError(
                f"{source}: field 'id' is {data['id']!r} but the content hashes to {basis.id!r} "
                "(file edited or corrupt)"
            )
        return basis

    def save(self, path: str | Path) -> None:
        atomic_write_text(path, json.dumps(self.to_dict(), indent=1, allow_nan=False) + "\n")

    @classmethod
    def load(cls, path: str | Path) -> Basis:
        return cls.from_dict(read_json_file(path, "basis file"), str(path))


# ---------------------------------------------------------------------------------------------
def build_basis_from_rows(
    rows: np.ndarray,
    *,
    family: str,
    members: Sequence[str] | None = None,
    k: int = DEFAULT_K,
    margin: float = DEFAULT_MARGIN,
    cmrt: Mapping[str, Any] | None = None,
) -> Basis:
    """PCA of an (n, p) data matrix (params + duration column). Needs n >= k + 1, k <= p - 1."""
    A = np.asarray(rows, dtype=float)
    if A.ndim != 2 or A.shape[1] < 2:
        raise BasisError("PCA data must be a matrix with at least 2 columns (params + duration)")
    n, p = A.shape
    if not np.all(np.isfinite(A)):
        raise BasisError("PCA data must be finite")
    if k < 1 or k > p - 1:
        raise BasisError(f"k must be between 1 and {p - 1} for {p - 1} parameters, got {k}")
    if n < k + 1:
        raise BasisError(
            f"family {family!r}: {n} results are too few for k = {k} components "
            f"(need at least {k + 1})"
        )
    if margin < 0:
        raise BasisError("margin must be >= 0")
    mean = A.mean(axis=0)
    C = A - mean
    _, S, Vt = np.linalg.svd(C, full_matrices=False)
    total = float(np.sum(S**2))
    if total <= 0.0:
        raise BasisError(f"family {family!r}: all results are identical, no variance to analyse")
    for i in range(Vt.shape[0]):  # deterministic signs
        if Vt[i, np.argmax(np.abs(Vt[i]))] < 0:
            Vt[i] = -Vt[i]
    comps = Vt[:k].copy()
    scores = C @ comps.T
    smin, smax = scores.min(axis=0), scores.max(axis=0)
    rng = smax - smin
    half = np.where(rng > 1e-9, 0.0, MIN_BOX_HALF_WIDTH)
    lo = smin - margin * rng - half
    hi = smax + margin * rng + half
    return Basis(
        family=family,
        k=k,
        mean=mean,
        components=comps,
        variance_explained=S**2 / total,
        members=list(members) if members is not None else [f"row{i}" for i in range(n)],
        score_lo=lo,
        score_hi=hi,
        cmrt=dict(cmrt or {}),
        margin=float(margin),
    )


def build_basis(
    results: Sequence[CmrtSample],
    *,
    k: int = DEFAULT_K,
    margin: float = DEFAULT_MARGIN,
    family: str | None = None,
) -> Basis:
    """Basis of a family of full-space CMRTs (optimisation results or library entries: rows
    params + the clip's task duration).

    All results must share the family (or match `family` if given) and the CMRT settings.
    """
    if len(results) == 0:
        raise BasisError("no results to build a basis from")
    fam = family or results[0].family
    cmrt0 = dict(results[0].cmrt)
    dim0 = results[0].dimension
    rows = []
    for r in results:
        if r.family != fam:
            raise BasisError(f"result {r.name!r} is of family {r.family!r}, not {fam!r}")
        if r.dimension != dim0 or dict(r.cmrt) != cmrt0:
            raise BasisError(
                f"result {r.name!r} uses different CMRT settings than {results[0].name!r}"
            )
        rows.append(list(r.params) + [float(r.duration)])
    # the settings as the spec model fills them (defaults included), without parsing a spec
    cmrt = CmrtConfig.model_validate(cmrt0).model_dump()
    return build_basis_from_rows(
        np.array(rows),
        family=fam,
        members=[r.name for r in results],
        k=k,
        margin=margin,
        cmrt=cmrt,
    )


__all__ = [
    "DEFAULT_K",
    "DEFAULT_MARGIN",
    "MIN_BOX_HALF_WIDTH",
    "Basis",
    "build_basis",
    "build_basis_from_rows",
]
