"""`cmrt motion import`: a BVH clip as a `motion` task spec (sim.motion_import, docs/motion.md).

    cmrt motion import CLIP.bvh --character humanoid [--map MAP.yaml] [--start S --end E]
                       [--rate FPS] [--name NAME] --out motion.yaml

Prints what the import did (the section, the map, the sagittal plane, what was clipped) and
writes the spec, which `cmrt simulate` and `cmrt optimize` take as it is. A bad file, map or
option: one line naming it, exit 2, nothing written.
"""

from __future__ import annotations

import argparse
import os
import shlex
from pathlib import Path
from typing import Any

from cmrt.cmdline import die


def _number(text: str) -> float:
    """An argparse type: a finite number."""
    try:
        v = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a number") from None
    if v != v or v in (float("inf"), float("-inf")):
        raise argparse.ArgumentTypeError(f"must be finite, got {text}")
    return v


def command_line(args: argparse.Namespace) -> str:
    """The command as given but its --out (the written spec's header names it, so that the
    same command gives the same file wherever it writes it)."""
    parts = ["cmrt", "motion", "import", args.clip]
    if args.character is not None:
        parts += ["--character", args.character]
    for flag, v in (("--map", args.map), ("--start", args.start), ("--end", args.end),
                    ("--rate", args.rate), ("--name", args.name),
                    ("--cutoff", None if args.cutoff == 6.0 else args.cutoff),
                    ("--legs", None if args.legs == "average" else args.legs)):
        if v is not None:
            parts += [flag, f"{v:g}" if isinstance(v, float) else str(v)]
    if args.joints:
        parts += ["--joints", *args.joints]
    return shlex.join(parts)


def cmd_motion_import(args: argparse.Namespace) -> int:
    from optim._io import atomic_write_text
    from sim.motion_import import ImportOptions, import_motion, spec_text
    from sim.spec import parse_spec

    options = ImportOptions(args.start, args.end, args.rate, args.cutoff, args.legs,
                            tuple(args.joints) if args.joints else None, args.name)
    imp = import_motion(args.clip, args.character, args.map, options)
    block = imp.spec["character"]
    if "file" in block:  # a character file: named relative to the written spec, as specs do
        rel = os.path.relpath(Path(block["file"]).resolve(), Path(args.out).resolve().parent)
        imp.spec["character"] = {"file": Path(rel).as_posix()}
    parse_spec(imp.inline_spec(), args.out)  # what is written is a spec the simulator takes
    text = spec_text(imp, command_line(args))
    try:
        atomic_write_text(args.out, text)
    except OSError as err:
        return die(f"--out: cannot write {args.out} ({err.strerror or err})")
    for line in imp.report:
        print(line)
    print(f"wrote {args.out} ({len(text.encode()) / 1e3:.1f} kB): cmrt simulate {args.out}")
    return 0


def add_parsers(sub: Any) -> None:
    """`cmrt motion import`."""
    m = sub.add_parser("motion", help="motions from mocap clips (docs/motion.md)")
    msub = m.add_subparsers(dest="motion_command", required=True)
    i = msub.add_parser(
        "import", help="a BVH clip as a motion task spec",
        description="Project a BVH clip onto the sagittal plane by bone directions, map it "
        "onto the character's hinges, resample it and keep it inside the joint limits; write "
        "a task spec that cmrt simulate and cmrt optimize take as it is (docs/motion.md).")
    i.add_argument("clip", metavar="CLIP.bvh")
    i.add_argument("--character",
                   help="a shipped character's name (default: the package's default "
                        "character) or a character file "
                        "(.yaml/.json, docs/characters.md), named in the spec by its path")
    i.add_argument("--map", metavar="MAP.yaml",
                   help="which clip bone each character segment follows (default: the "
                        "character's own segment names, else the built-in CMU and Mixamo "
                        "maps)")
    i.add_argument("--start", type=_number, metavar="S", help="first second of the clip")
    i.add_argument("--end", type=_number, metavar="E", help="last second of the clip")
    i.add_argument("--rate", type=_number, metavar="FPS",
                   help="frames per second written (default: the clip's, at most 60)")
    i.add_argument("--cutoff", type=_number, default=6.0, metavar="HZ",
                   help="low-pass cutoff of the angles, zero phase (default 6 Hz; 0: none)")
    i.add_argument("--joints", nargs="+", metavar="JOINT",
                   help="write only these joints (default: every mapped one); the others "
                        "keep the standing pose")
    i.add_argument("--name", help="the spec's name (default: the clip's file name)")
    i.add_argument("--legs", choices=("average", "each"), default="average",
                   help="average: both legs follow the mean of the clip's two (the feet stay "
                        "planted together; the default); each: as the clip has them")
    i.add_argument("--out", required=True, metavar="motion.yaml")
    i.set_defaults(func=cmd_motion_import)
