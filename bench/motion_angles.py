"""An imported motion's hinge angles three ways, as an SVG figure: the clip's own sagittal
bone angles (no filter), the reference the spec holds (filtered, resampled) and what the
simulated character did, for a few joints.

    .venv/bin/python bench/motion_angles.py examples/motion_bend.yaml \
        tests/data/cmu_02_06_bend.bvh --map tests/data/cc3_map.yaml --end 2.5 \
        --joints waist shoulder_r elbow_r --out docs/img/motion_bend_angles.svg

Prints the largest difference (degrees) between each pair of curves per joint.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from sim import load_spec
from sim.export import sample_motion
from sim.motion_import import ImportOptions, import_motion
from sim.rollout import Rollout

W, H, PAD = 900, 210, 50  # px: one panel
COLOURS = {"clip (no filter)": "#bbbbbb", "reference": "#1f77b4", "simulated": "#d62728"}
#: px: the clip's line drawn wide under the others, which it would hide (they differ by ~1 deg).
WIDTHS = {"clip (no filter)": 5.0, "reference": 1.5, "simulated": 1.0}


def _panel(name: str, curves: dict[str, tuple[np.ndarray, np.ndarray]], top: int,
           t_range: tuple[float, float]) -> list[str]:
    lo = min(float(c[1].min()) for c in curves.values())
    hi = max(float(c[1].max()) for c in curves.values())
    lo, hi = lo - 0.05 * (hi - lo + 1), hi + 0.05 * (hi - lo + 1)

    def x(t: float) -> float:
        return PAD + (W - 2 * PAD) * (t - t_range[0]) / (t_range[1] - t_range[0])

    def y(v: float) -> float:
        return top + H - PAD / 2 - (H - PAD) * (v - lo) / (hi - lo)

    out = [f'<text x="{PAD}" y="{top + 14}" font-size="14">{name} (degrees)</text>',
           f'<rect x="{PAD}" y="{top + PAD / 2}" width="{W - 2 * PAD}" height="{H - PAD}" '
           'fill="none" stroke="#ccc"/>']
    for v in np.linspace(lo, hi, 5)[1:-1]:
        out.append(f'<text x="{PAD - 4}" y="{y(v) + 4:.1f}" font-size="10" '
                   f'text-anchor="end">{v:.0f}</text>')
    for t in np.arange(np.ceil(t_range[0]), t_range[1] + 1e-9, 0.5):
        out.append(f'<text x="{x(t):.1f}" y="{top + H - 8}" font-size="10" '
                   f'text-anchor="middle">{t:g} s</text>')
    for label, (t, v) in curves.items():
        pts = " ".join(f"{x(a):.1f},{y(b):.1f}" for a, b in zip(t, v, strict=True))
        out.append(f'<polyline points="{pts}" fill="none" stroke="{COLOURS[label]}" '
                   f'stroke-width="{WIDTHS[label]}"/>')
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("spec")
    ap.add_argument("clip")
    ap.add_argument("--map")
    ap.add_argument("--end", type=float)
    ap.add_argument("--joints", nargs="+", default=["waist", "shoulder_r", "elbow_r"])
    ap.add_argument("--out", required=True)
    args = ap.parse_args(argv)
    spec = load_spec(args.spec)
    raw = import_motion(args.clip, spec.character.model, args.map,
                        ImportOptions(end=args.end, cutoff=0.0))
    sim = Rollout(spec)
    try:
        ev = sim.run(None, traces=True)
    finally:
        sim.close()
    ch = sim.character
    task = spec.task
    start = task.first_frame_time(spec.clip)
    ref_t = start + np.arange(len(task.frames)) * task.interval
    m = sample_motion(ev, 100.0)
    svg = [f'<svg xmlns="http://www.w3.org/2000/svg" width="{W}" '
           f'height="{H * len(args.joints) + 30}" font-family="sans-serif">',
           '<rect width="100%" height="100%" fill="white"/>']
    for n, joint in enumerate(args.joints):
        j = ch.hinge_index(joint)
        k = task.joints.index(joint)
        curves = {
            "clip (no filter)": (start + raw.times, np.degrees(
                raw.angles[:, raw.spec["task"]["joints"].index(joint)])),
            "reference": (ref_t, np.array([f[k] for f in task.frames])
                          + np.degrees(ch.standing_offsets[j])),
            "simulated": (m.t, np.degrees(m.q[:, 3 + j])),
        }
        svg += _panel(joint, curves, 30 + n * H, (0.0, spec.clip.length))
        ref = np.interp(curves["clip (no filter)"][0], *curves["reference"])
        sim_at = np.interp(ref_t, *curves["simulated"])
        print(f"{joint}: reference - clip up to "
              f"{np.abs(ref - curves['clip (no filter)'][1]).max():.2f} deg, simulated - "
              f"reference up to {np.abs(sim_at - curves['reference'][1]).max():.2f} deg")
    for i, (label, colour) in enumerate(COLOURS.items()):
        svg.append(f'<text x="{PAD + 200 * i}" y="18" font-size="12" fill="{colour}">'
                   f'&#9644; {label}</text>')
    svg.append("</svg>")
    Path(args.out).write_text("\n".join(svg) + "\n")
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
