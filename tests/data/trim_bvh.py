"""Trim a BVH clip for the repository: keep some joints and a section of frames, nothing else
changed (the kept channels' values are copied as they are written in the source).

    python tests/data/trim_bvh.py SOURCE.bvh OUT.bvh --first F --last L [--step S]
                                  [--keep JOINT ...]

A joint is dropped with its whole subtree; every joint on the path from the root to a kept
joint is kept too (so the kept joints' world poses are the source's). A kept joint whose
children were all dropped gets an End Site at its first dropped child's OFFSET. The frames
kept are F, F + S, ... up to L (0-based, inclusive), and the Frame Time is multiplied by S.
tests/data/README.md records the commands that made the clips here.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT))

from sim.bvh import read_bvh  # noqa: E402


def _keep_set(clip, keep: list[str] | None) -> set[int]:
    if not keep:
        return set(range(len(clip.joints)))
    out: set[int] = set()
    for name in keep:
        i = clip.index(name)
        while i >= 0 and i not in out:
            out.add(i)
            i = clip.joints[i].parent
    return out


def _fmt(v) -> str:
    return " ".join(f"{x:.6f}" for x in v)


def _hierarchy(clip, kept: set[int]) -> list[str]:
    lines = ["HIERARCHY"]

    def write(i: int, depth: int) -> None:
        j = clip.joints[i]
        pad = "\t" * depth
        lines.append(f"{pad}{'ROOT' if j.parent < 0 else 'JOINT'} {j.name}")
        lines.append(f"{pad}{{")
        lines.append(f"{pad}\tOFFSET {_fmt(j.offset)}")
        lines.append(f"{pad}\tCHANNELS {len(j.channels)} {' '.join(j.channels)}")
        kids = clip.children(i)
        for k in kids:
            if k in kept:
                write(k, depth + 1)
        end = j.end_site
        if end is None and kids and not any(k in kept for k in kids):
            end = clip.joints[kids[0]].offset
        if end is not None:
            lines.extend([f"{pad}\tEnd Site", f"{pad}\t{{", f"{pad}\t\tOFFSET {_fmt(end)}",
                          f"{pad}\t}}"])
        lines.append(f"{pad}}}")

    write(0, 0)
    return lines


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("source")
    ap.add_argument("out")
    ap.add_argument("--first", type=int, required=True)
    ap.add_argument("--last", type=int, required=True)
    ap.add_argument("--step", type=int, default=1)
    ap.add_argument("--keep", nargs="+")
    args = ap.parse_args(argv)
    clip = read_bvh(args.source)
    kept = _keep_set(clip, args.keep)
    # The source's frame lines as written (its own digits), by channel column.
    text = Path(args.source).read_text(encoding="utf-8", errors="replace").splitlines()
    start = next(i for i, line in enumerate(text) if line.strip().startswith("Frame Time:"))
    rows = [line.split() for line in text[start + 1:] if line.strip()]
    cols, c = [], 0
    for i, j in enumerate(clip.joints):
        if i in kept:
            cols += range(c, c + len(j.channels))
        c += len(j.channels)
    frames = list(range(args.first, args.last + 1, args.step))
    frame_time = float(text[start].split()[2]) * args.step
    lines = _hierarchy(clip, kept)
    lines += ["MOTION", f"Frames: {len(frames)}", f"Frame Time: {frame_time:.7g}"]
    lines += [" ".join(rows[f][k] for k in cols) for f in frames]
    Path(args.out).write_text("\n".join(lines) + "\n")
    print(f"{args.out}: {sum(1 for i in kept)} of {len(clip.joints)} joints, {len(frames)} "
          f"frames, {Path(args.out).stat().st_size} bytes")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
