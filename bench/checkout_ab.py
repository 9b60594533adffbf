"""`cmrt bench` of two checkouts in one run, alternated: the speed ratios before and after.

    .venv/bin/python -m bench.checkout_ab OTHER_CHECKOUT [SPEC ...] [--rounds 3]
        [--seconds 3] [--repeat 3]

OTHER_CHECKOUT is another checkout of the repository (e.g. a `git worktree add --detach` of
the commit before a change). Each round runs `cmrt bench --json` once with that checkout's
packages first on the path (`PYTHONPATH`, this interpreter) and once with this checkout's,
in alternating order, so that a change of the machine's load reaches both. Default specs: the
task worlds of docs/benchmarks.md (catch, punch, domino, sumo pull, lion hit). Reported per
world and checkout: the median and range over the rounds of controller / replayed ODE (task
worlds) and controller / raw ODE (every world; the quiet stance has no replay target of its
own), and the load average before and after. Ratios within one run are the comparable figures.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
DEFAULT = ["examples/catch.yaml", "examples/punch.yaml", "examples/domino.yaml",
           "examples/sumo_pull.yaml", "examples/lion_hit.yaml"]


def _bench(checkout: Path, specs: list[str], seconds: float, repeat: int) -> list[dict]:
    cmd = [str(Path(sys.executable).with_name("cmrt")), "bench", "--json", "--seconds",
           str(seconds), "--repeat", str(repeat), *[str(ROOT / s) for s in specs]]
    env = {**os.environ, "PYTHONPATH": str(checkout)}
    out = subprocess.run(cmd, cwd=checkout, env=env, check=True, capture_output=True,
                         text=True).stdout
    return json.loads(out)


def _load() -> str:
    return " ".join(f"{x:.1f}" for x in os.getloadavg())


def _cell(values: list[float]) -> str:
    return f"{statistics.median(values):.3f} ({min(values):.3f}-{max(values):.3f})"


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("other", type=Path, help="the other checkout (before)")
    ap.add_argument("specs", nargs="*", default=DEFAULT)
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--seconds", type=float, default=3.0)
    ap.add_argument("--repeat", type=int, default=3)
    args = ap.parse_args(argv)
    builds = {"before": args.other.resolve(), "after": ROOT}
    ratios: dict[tuple[str, str, str], list[float]] = {}
    print(f"load before: {_load()}", flush=True)
    for r in range(args.rounds):
        order = ("before", "after") if r % 2 == 0 else ("after", "before")
        for build in order:
            for row in _bench(builds[build], args.specs, args.seconds, args.repeat):
                world = row.get("spec", "quiet stance (bench)")
                for key in ("controller_over_raw_ode", "controller_over_replay_ode"):
                    ratios.setdefault((world, key, build), []).append(row[key])
        print(f"round {r + 1} done, load {_load()}", flush=True)
    worlds = list(dict.fromkeys(w for w, _k, _b in ratios))
    print("| world | controller / replayed ODE, before | after | controller / raw ODE, "
          "before | after |")
    print("|---|---|---|---|---|")
    for w in worlds:
        cells = [_cell(ratios[(w, key, b)]) for key in ("controller_over_replay_ode",
                                                         "controller_over_raw_ode")
                 for b in ("before", "after")]
        print(f"| {w} | " + " | ".join(cells) + " |")
    print(f"load after: {_load()}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
