"""Robust CMRTs: the `optimize.robust` block of a spec and its fixed set of scene variants.

    optimize:
      robust:
        vary: {task.mass: [112, 160]}   # 1-4 dotted paths of the spec's numbers -> [lo, hi]
        samples: 5                      # K variants (2-32)
        aggregate: mean                 # mean | worst: how K objectives make a candidate's

The K variants are a fixed function of the block alone (`variant_values`), so a robust
objective is deterministic and every process builds the same variants:
  * each path takes K evenly spaced levels over its range, both ends included:
    level i = lo + (hi - lo) * i / (K - 1) (i = 0 .. K-1; the ends exactly lo and hi);
  * with one path, variant i is level i;
  * with several (a Latin hypercube: every level of every path used once), the paths are taken
    in sorted order; the first keeps levels in order, each other path j permutes them by
    sorting the indices i on sha256("<block hash>:<j>:<i>"), where the block hash is the
    sha256 of the block's canonical JSON. No random generator whose stream could change
    between library versions is involved.
A variant is the spec's document with the paths set to the variant's values and no `robust`
block: an ordinary spec (`variant_document`). Parsing a robust spec checks every variant
parses (`sim.spec`'s validator), so a range that leaves a field's bounds or breaks a rule of
the task is refused at the boundary, naming the path and the rule.
"""

from __future__ import annotations

import copy
import hashlib
from typing import Annotated, Any, Literal

from pydantic import Field

from cmrt.canonical import canonical_json
from sim.specbase import StrictModel, count

#: Most paths one robust block may vary (a Latin hypercube over more says little with K <= 32).
MAX_ROBUST_PATHS = 4
#: Fewest and most variants per candidate (each one clip per candidate and generation).
MIN_SAMPLES, MAX_SAMPLES = 2, 32
#: Blocks whose numbers are not the scene: they shape the search (`cmrt`, `optimize`).
NOT_SCENE = ("optimize", "cmrt")

_PATH = r"^[A-Za-z_][A-Za-z0-9_]*(\.[A-Za-z0-9_]+)+$"
Range = Annotated[list[float], Field(min_length=2, max_length=2)]


class RobustConfig(StrictModel):
    """Optimise one CMRT for a range of scenes (see the module docstring)."""

    vary: Annotated[dict[Annotated[str, Field(pattern=_PATH, max_length=200)], Range],
                    Field(min_length=1, max_length=MAX_ROBUST_PATHS)]
    samples: count(MIN_SAMPLES, MAX_SAMPLES, "variants") = 5
    aggregate: Literal["mean", "worst"] = "mean"

    @property
    def paths(self) -> list[str]:
        """The varied paths in the variants' order (sorted)."""
        return sorted(self.vary)

    def block_hash(self) -> str:
        return hashlib.sha256(canonical_json(self.model_dump(mode="json")).encode()).hexdigest()


def levels(lo: float, hi: float, k: int) -> list[float]:
    """K evenly spaced values over [lo, hi], both ends exact."""
    out = [lo + (hi - lo) * i / (k - 1) for i in range(k)]
    out[0], out[-1] = float(lo), float(hi)
    return out


def _order(block: str, j: int, k: int) -> list[int]:
    key = [hashlib.sha256(f"{block}:{j}:{i}".encode()).hexdigest() for i in range(k)]
    return sorted(range(k), key=lambda i: key[i])


def variant_values(robust: RobustConfig) -> list[dict[str, float]]:
    """The K variants' values, path -> value, in variant order (see the module docstring)."""
    k, block = robust.samples, robust.block_hash()
    columns = []
    for j, path in enumerate(robust.paths):
        lo, hi = robust.vary[path]
        lv = levels(lo, hi, k)
        columns.append(lv if j == 0 else [lv[i] for i in _order(block, j, k)])
    return [{p: columns[j][i] for j, p in enumerate(robust.paths)} for i in range(k)]


def set_dotted(doc: dict[str, Any], path: str, value: float) -> None:
    """Set the entry at a dotted path of a spec document in place (list entries by index)."""
    node: Any = doc
    *head, last = path.split(".")
    for part in head:
        node = node[int(part)] if isinstance(node, list) else node[part]
    if isinstance(node, list):
        node[int(last)] = value
    else:
        node[last] = value


def variant_document(document: dict[str, Any], values: dict[str, float]) -> dict[str, Any]:
    """A spec document with `values` set and without its robust block (an ordinary spec)."""
    doc = copy.deepcopy(document)
    doc.get("optimize", {}).pop("robust", None)
    for path, v in values.items():
        set_dotted(doc, path, v)
    return doc


__all__ = ["MAX_ROBUST_PATHS", "MAX_SAMPLES", "MIN_SAMPLES", "NOT_SCENE", "RobustConfig", "levels",
           "set_dotted", "variant_document", "variant_values"]
