"""What the momentum QP plans against what ODE does: the centre of pressure per QP solve.

    .venv/bin/python bench/qp_diagnosis.py SPEC [--cmrt RESULT.json] [--from 0.9] [--to 1.8]
        [--every 1] [--json]

At every QP solve (60 Hz) of one clip it prints
  * the desired horizontal linear-momentum rate and angular-momentum rate (about the CM),
  * the rates the chosen qdd* gives in the controller's model (A_L qdd*, A_H qdd*; the QP
    ignores the velocity-product terms, as the paper does),
  * the centre of pressure those planned rates imply, relative to the support centre:
    `planned`: p = c_x + (Hdot - c_y F_x) / F_y with the model's rates, and `planned+v`: the
    same with the velocity-product terms added (`sim.dynamics.momentum_bias`),
  * the CP that ODE measured at that step.
The summary counts the solves whose planned CoP lies outside the support and the RMS gap between
`planned+v` and the measured CP. No assertions: a diagnostic for the controller's limits (see
docs/physics.md, "Why the fast bend is not halved").
"""

from __future__ import annotations

import argparse
import json
import math
import sys

import numpy as np

from sim.dynamics import GRAVITY, momentum_bias
from sim.physics import DT
from sim.rollout import Rollout
from sim.spec import load_spec


def diagnose(spec_path: str, cmrt_path: str | None) -> tuple[list[dict], float]:
    spec = load_spec(spec_path)
    sim = Rollout(spec)
    cmrt = None
    if cmrt_path:
        from optim.result import OptimizationResult

        cmrt = OptimizationResult.load(cmrt_path).spline()
    ctl = sim.controller
    rows: list[dict] = []
    solve = ctl.solve

    def recording_solve(t, q, qd, c, cd, A_L, A_H, Js, support, c_ref, cd_ref, *rest):
        qdd = solve(t, q, qd, c, cd, A_L, A_H, Js, support, c_ref, cd_ref, *rest)
        m = ctl.mass
        ldot_des, hdot_des = ctl.desired_rates(ctl.schedule(t), c, cd, support, c_ref, cd_ref)
        lo, hi = support
        centre = 0.5 * (lo + hi)
        l_qp, h_qp = A_L @ qdd, float(A_H @ qdd)
        a = sim.arrays
        bl, bh, _ = momentum_bias(q, qd, a.parent, a.a_par, a.a_chi, a.mass, a.feet,
                                  a.sole_local)

        def cop(ldot: np.ndarray, hdot: float) -> float:
            f = ldot + np.array([0.0, m * GRAVITY])
            return float(c[0] + (hdot - c[1] * f[0]) / f[1] - centre)

        rows.append({
            "t": t, "ldot_x_des": float(ldot_des[0]), "ldot_x_qp": float(l_qp[0]),
            "hdot_des": float(hdot_des), "hdot_qp": h_qp,
            "planned": cop(l_qp, h_qp), "planned_v": cop(l_qp + bl, h_qp + bh),
            "half_support": 0.5 * (hi - lo),
        })
        return qdd

    ctl.solve = recording_solve
    try:
        ev = sim.run(cmrt, traces=True)
    finally:
        sim.close()
    err = ev.traces.error
    for r in rows:
        k = int(round(r["t"] / DT))
        r["measured"] = float(err[k]) if k < len(err) and not math.isnan(err[k]) else None
    return rows, ev.objective


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("spec")
    p.add_argument("--cmrt", help="an optimisation result whose CMRT to replay")
    p.add_argument("--from", dest="t0", type=float, default=0.0)
    p.add_argument("--to", dest="t1", type=float, default=math.inf)
    p.add_argument("--every", type=int, default=1, help="print every n-th QP solve")
    p.add_argument("--json", action="store_true")
    args = p.parse_args(argv)
    rows, objective = diagnose(args.spec, args.cmrt)
    shown = [r for r in rows if args.t0 <= r["t"] <= args.t1]
    outside = [r for r in shown if abs(r["planned"]) > r["half_support"]]
    gaps = [r["planned_v"] - r["measured"] for r in shown if r["measured"] is not None]
    summary = {
        "objective": objective, "solves": len(shown), "planned_outside_support": len(outside),
        "worst_planned_cm": 100 * max((abs(r["planned"]) for r in shown), default=0.0),
        "rms_planned_v_minus_measured_cm": 100 * float(np.sqrt(np.mean(np.square(gaps))))
        if gaps else None,
    }
    if args.json:
        print(json.dumps({"summary": summary, "rows": shown}))
        return 0
    print("    t   Lx' des    Lx' qp   H' des    H' qp   planned planned+v  measured  (cm from "
          "the support centre)")
    for r in shown[:: max(1, args.every)]:
        meas = "      -" if r["measured"] is None else f"{100 * r['measured']:+7.1f}"
        print(f"{r['t']:5.3f} {r['ldot_x_des']:9.1f} {r['ldot_x_qp']:9.1f} {r['hdot_des']:8.1f} "
              f"{r['hdot_qp']:8.1f}   {100 * r['planned']:+7.1f}   {100 * r['planned_v']:+7.1f}"
              f"   {meas}")
    for k, v in summary.items():
        print(f"{k:>32}: {v:.4g}" if isinstance(v, float) else f"{k:>32}: {v}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
