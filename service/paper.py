"""Reference figures of the paper (Anticipatory Balance Control, CAVW 2016) that the pages
show beside the product's own, keyed by what they measure."""

from __future__ import annotations

from typing import Any

#: Table 2 (domino, wall mass in kg): per left-out mass, the reduced-space run's convergence
#: iterations and objective (itr_r, fv_r), the full-space run's (itr_u, fv_u), the speed-up S
#: in convergence time and the relative error Re (%).
TABLE2: dict[tuple[str, str], list[dict[str, float]]] = {
    ("domino", "task.mass"): [
        {"value": 30, "itr_r": 71, "fv_r": 1.096, "itr_u": 143, "fv_u": 1.086, "speedup": 2.01,
         "relative_error_pct": 0.9},
        {"value": 60, "itr_r": 56, "fv_r": 1.128, "itr_u": 270, "fv_u": 1.09, "speedup": 4.82,
         "relative_error_pct": 3.4},
        {"value": 90, "itr_r": 32, "fv_r": 1.325, "itr_u": 231, "fv_u": 1.299, "speedup": 7.21,
         "relative_error_pct": 2.0},
        {"value": 110, "itr_r": 113, "fv_r": 1.467, "itr_u": 451, "fv_u": 1.467,
         "speedup": 3.99, "relative_error_pct": 0.0},
        {"value": 150, "itr_r": 163, "fv_r": 1.741, "itr_u": 309, "fv_u": 1.726,
         "speedup": 1.89, "relative_error_pct": 0.8},
    ],
}


def table2(task: str, param: str) -> list[dict[str, Any]] | None:
    """The paper's Table 2 rows for a family of `task` along `param`, if the paper has them."""
    rows = TABLE2.get((task, param))
    return None if rows is None else [dict(r) for r in rows]
